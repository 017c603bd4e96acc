//! `btfrig compress`, `btfrig sparse select|reconstruct`, `btfrig dataset export` and the
//! model part of `btfrig dataset info`: argument handling and display over
//! `btfrig-compress` (docs/compression.md).

use std::path::{Path, PathBuf};

use anyhow::Context;
use btfrig_compress::dataset::DatasetSource;
use btfrig_compress::sparse::{self, Strategy};
use btfrig_compress::{build, file, ubo, ColorModel, Method, Model, ModelParams, Precision};
use clap::{Args, Subcommand};

/// Model knobs shared by `compress` and the benchmark.
#[derive(Debug, Clone, Args)]
pub struct ModelArgs {
    /// fmf (full matrix), pvmf (per view) or pcmf (per cluster, local PCA).
    #[arg(long, default_value = "fmf")]
    pub method: String,
    /// PCMF: clusters of texels.
    #[arg(long, default_value_t = 32)]
    pub clusters: usize,
    /// Terms per channel: one number for all three, or Y,C,C (default: fmf 32,16,16; pvmf and
    /// pcmf 8,4,4).
    #[arg(long)]
    pub terms: Option<String>,
    /// Colour model: rgb, yuv, ylog-uv.
    #[arg(long, default_value = "yuv")]
    pub color: String,
    /// Stored precision: f16 or f32.
    #[arg(long, default_value = "f16")]
    pub precision: String,
    /// Power iterations of the randomized SVD (two passes over the data each).
    #[arg(long, default_value_t = 1)]
    pub power_iters: usize,
    /// Oversampling of the randomized SVD.
    #[arg(long, default_value_t = 10)]
    pub oversample: usize,
    /// Seed of the random test matrices and the clustering.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// PCMF: local-PCA iterations on the data after the first per-cluster models (each one
    /// reassignment pass and the models again: 1 + 2 + 2 x power-iters passes), 0..=20.
    #[arg(long, default_value_t = 2)]
    pub refine_iters: usize,
    /// PCMF: store the cluster bases in a shared angular basis of K terms per channel (an FMF
    /// of K terms, W once; per cluster a mean and a K x terms basis in W's coefficients): far
    /// smaller than PCMF's own basis per cluster. K from the largest --terms to 1024 and at
    /// most the captures and the texels.
    #[arg(long, value_name = "K")]
    pub shared_basis: Option<usize>,
    /// PCMF with --shared-basis: local-PCA iterations on the coefficients in the shared basis
    /// (in memory, no pass over the data), 0..=50.
    #[arg(long, default_value_t = 5)]
    pub shared_iters: usize,
}

impl ModelArgs {
    /// The validated parameters.
    pub fn params(&self) -> anyhow::Result<ModelParams> {
        let method = match self.method.as_str() {
            "fmf" => Method::Fmf,
            "pvmf" => Method::Pvmf,
            "pcmf" => Method::Pcmf { clusters: self.clusters, shared_basis: self.shared_basis },
            m => anyhow::bail!("--method {m:?}: allowed fmf, pvmf, pcmf"),
        };
        if let (Some(k), false) = (self.shared_basis, self.method == "pcmf") {
            anyhow::bail!("--shared-basis {k}: only for --method pcmf (not {})", self.method);
        }
        let mut p = ModelParams::new(method);
        p.color = ColorModel::from_name(&self.color)
            .ok_or_else(|| anyhow::anyhow!("--color {:?}: allowed rgb, yuv, ylog-uv", self.color))?;
        p.precision = match self.precision.as_str() {
            "f16" => Precision::F16,
            "f32" => Precision::F32,
            x => anyhow::bail!("--precision {x:?}: allowed f16, f32"),
        };
        if let Some(t) = &self.terms {
            p.terms = parse_terms(t)?;
        }
        p.power_iters = self.power_iters;
        p.oversample = self.oversample;
        p.seed = self.seed;
        p.refine_iters = self.refine_iters;
        p.shared_iters = self.shared_iters;
        p.validate()?;
        Ok(p)
    }
}

/// `8` or `8,4,4`.
pub fn parse_terms(t: &str) -> anyhow::Result<[usize; 3]> {
    let v: Vec<usize> = t
        .split(',')
        .map(|s| s.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--terms {t:?}: expected N or Y,C,C (positive integers)"))?;
    match v.as_slice() {
        [k] => Ok([*k; 3]),
        [a, b, c] => Ok([*a, *b, *c]),
        _ => anyhow::bail!("--terms {t:?}: expected N or Y,C,C (positive integers)"),
    }
}

/// `btfrig compress`.
#[derive(Debug, Args)]
pub struct CompressArgs {
    /// The dataset directory (read only: textures are never modified).
    pub dir: PathBuf,
    /// Model knobs.
    #[command(flatten)]
    pub model: ModelArgs,
    /// Model file to write (default: `<DIR>.<method>.btfm` next to the dataset).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing model file.
    #[arg(long)]
    pub overwrite: bool,
    /// Skip the extra pass that measures the model against the dataset.
    #[arg(long)]
    pub no_eval: bool,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

pub use btfrig_measurement::sinks::{default_model_path, path_label};

/// Peak resident memory of this process (Linux `VmHWM`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Builds a model of a dataset and writes it.
pub fn compress(a: &CompressArgs) -> anyhow::Result<()> {
    let params = a.model.params()?;
    let out = a.out.clone().unwrap_or_else(|| default_model_path(&a.dir, &path_label(&params.method)));
    if out.exists() && !a.overwrite {
        anyhow::bail!(
            "{} already exists: refusing to overwrite it (--overwrite to replace, or --out FILE)",
            out.display()
        );
    }
    let mut src = DatasetSource::open(&a.dir)?;
    let layout = src.layout().clone();
    let captures = layout.n_measured();
    let (model, stats) = build::<f32>(layout, &params, &mut src)?;
    let rel = if a.no_eval { None } else { Some(btfrig_compress::eval::error_against(&model, &mut src)?.rel_rmse()) };
    let raw = (captures * model.layout.texels() * 3 * 2) as f64;
    let source = serde_json::json!({
        "dataset": a.dir.display().to_string(),
        "plan_hash": src.manifest().plan.hash,
        "captures": captures,
        "params": params,
        "build": stats,
        "rel_rmse_vs_dataset": rel,
    });
    let bytes = file::write(&out, &model, source, a.overwrite)?;
    let ratio = raw / bytes as f64;
    let rss = peak_rss_bytes();
    if a.json {
        let j = serde_json::json!({
            "model": out.display().to_string(), "method": params.method.name(), "terms": params.terms,
            "shared_basis": params.method.shared_basis(), "payload_bytes": model.payload_bytes(),
            "color": params.color.name(), "captures": captures, "texels": model.layout.texels(),
            "passes": stats.passes, "pass_s": stats.pass_s, "build_s": stats.total_s,
            "builder_peak_bytes": stats.peak_bytes, "process_peak_rss_bytes": rss,
            "file_bytes": bytes, "raw_half_bytes": raw, "compression_ratio": ratio, "rel_rmse_vs_dataset": rel,
            "lights": model.layout.n_light(), "views": model.layout.n_view(),
            "view_ids": model.layout.captures.as_ref().map(|c| c.view_ids.clone()),
        });
        println!("{j}");
        return Ok(());
    }
    println!(
        "dataset   {} ({captures} captures, {}x{} texels)",
        a.dir.display(),
        model.layout.width,
        model.layout.height
    );
    if let Some(c) = &model.layout.captures {
        println!(
            "layout    {} lights x {} views (dataset view ids {:?}), each capture's directions in the sample frame",
            model.layout.n_light(),
            model.layout.n_view(),
            c.view_ids
        );
    }
    println!(
        "model     {} {:?} terms, colour {}, {:?}",
        params.method.label(),
        params.terms,
        params.color.name(),
        params.precision
    );
    println!(
        "build     {} passes in {:.1} s ({}), builder peak {:.1} MB, process peak RSS {}",
        stats.passes,
        stats.total_s,
        stats.pass_s.iter().map(|s| format!("{s:.1}")).collect::<Vec<_>>().join(" + "),
        stats.peak_bytes as f64 / 1e6,
        rss.map_or("unknown".into(), |r| format!("{:.1} MB", r as f64 / 1e6))
    );
    println!(
        "file      {} ({:.2} MB), ratio {ratio:.1} : 1 against half-float textures",
        out.display(),
        bytes as f64 / 1e6
    );
    if let Some(r) = rel {
        println!("error     relative RMSE {r:.5} against the dataset's textures");
    }
    Ok(())
}

/// One-paragraph summary of a model file (header only).
pub fn describe(path: &Path) -> anyhow::Result<String> {
    let (h, size) = file::read_header(path)?;
    let terms: Vec<usize> = h.channels.iter().map(|c| c.first().map_or(0, |p| p.k)).collect();
    let captured = h.light.len() * h.view.len() - h.unmeasured.len();
    let raw = (captured * h.width * h.height * 3 * 2) as f64;
    let mut s = format!(
        "model     {}: {}{}{} terms {:?}, colour {}, {}, {} light x {} view, {}x{} texels, {:.2} MB, ratio {:.1} : 1",
        path.display(),
        h.method,
        h.clusters.map_or(String::new(), |c| format!(" {c} clusters,")),
        h.shared_basis.map_or(String::new(), |k| format!(" shared basis {k} terms (format version {}),", h.version)),
        terms,
        h.color,
        h.precision,
        h.light.len(),
        h.view.len(),
        h.width,
        h.height,
        size as f64 / 1e6,
        raw / size as f64
    );
    if let Some(r) = h.source.get("rel_rmse_vs_dataset").and_then(|v| v.as_f64()) {
        s.push_str(&format!(", rel RMSE {r:.5} vs its dataset"));
    }
    Ok(s)
}

/// Model files next to a dataset (`<DIR>.*.btfm`).
pub fn models_next_to(dir: &Path) -> Vec<PathBuf> {
    let Some(name) = dir.file_name().map(|n| n.to_string_lossy().into_owned()) else { return Vec::new() };
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let mut v: Vec<PathBuf> = std::fs::read_dir(parent)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let f = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            f.starts_with(&format!("{name}.")) && f.ends_with(&format!(".{}", file::EXTENSION))
        })
        .collect();
    v.sort();
    v
}

/// `btfrig dataset export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// The dataset directory.
    pub dir: PathBuf,
    /// ubo-dfmf (`!DFMF08FCR`, UBO2014, linear RGB) or ubo-fmf (`!FMF12FCER`, log domain).
    #[arg(long)]
    pub format: String,
    /// The `.btf` file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The model to export (default: the one model `<DIR>.*.btfm` next to the dataset; if
    /// there is none, an FMF in RGB is built from the dataset first).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Terms in the file (default: ubo-dfmf every term of an FMF model, 64 for others;
    /// ubo-fmf 64).
    #[arg(long)]
    pub rank: Option<usize>,
    /// Store f32 instead of f16.
    #[arg(long)]
    pub f32: bool,
    /// Replace an existing file.
    #[arg(long)]
    pub overwrite: bool,
}

/// Exports a dataset's model to a Bonn container.
pub fn export(a: &ExportArgs) -> anyhow::Result<()> {
    let fmt = match a.format.as_str() {
        "ubo-dfmf" => ubo::UboFormat::Dfmf,
        "ubo-fmf" => ubo::UboFormat::Fmf1,
        f => anyhow::bail!("--format {f:?}: allowed ubo-dfmf, ubo-fmf"),
    };
    if a.out.exists() && !a.overwrite {
        anyhow::bail!("{} already exists: refusing to overwrite it (--overwrite to replace)", a.out.display());
    }
    if let Some(r) = a.rank {
        anyhow::ensure!((1..=4096).contains(&r), "--rank {r}: allowed 1..=4096");
    }
    let model: Model = match &a.model {
        Some(p) => file::read(p)?,
        None => {
            let found = models_next_to(&a.dir);
            match found.as_slice() {
                [one] => {
                    println!("model     {}", one.display());
                    file::read(one)?
                }
                [] => {
                    let mut src = DatasetSource::open(&a.dir)?;
                    // A sampling no Bonn container holds is refused before the build.
                    ubo::check_exportable(src.layout())?;
                    println!("model     none next to the dataset: building an FMF (rgb, 64 terms) from it");
                    let mut p = ModelParams::new(Method::Fmf);
                    p.color = ColorModel::Rgb;
                    p.terms = [64; 3];
                    p.precision = Precision::F32;
                    build::<f32>(src.layout().clone(), &p, &mut src)?.0
                }
                many => anyhow::bail!(
                    "several models next to {}: {}; choose one with --model",
                    a.dir.display(),
                    many.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
                ),
            }
        }
    };
    let size = if a.f32 { 4 } else { 2 };
    let t = std::time::Instant::now();
    let (u, fit) = match fmt {
        ubo::UboFormat::Dfmf => {
            let rank = if model.method == Method::Fmf { a.rank } else { Some(a.rank.unwrap_or(64)) };
            ubo::to_dfmf(&model, rank, size)?
        }
        ubo::UboFormat::Fmf1 => ubo::to_fmf1(&model, a.rank.unwrap_or(64), size)?,
    };
    let bytes = u.write(&a.out, a.overwrite)?;
    let how = if model.method == Method::Fmf && fmt == ubo::UboFormat::Dfmf && model.color.is_linear() {
        "factors converted"
    } else {
        "re-encoded"
    };
    println!(
        "wrote     {} ({}, {} terms, f{}, {:.2} MB) in {:.1} s: {how}, relative RMS {} against the model (of the values written: terms kept, rounding to f{} included)",
        a.out.display(),
        a.format,
        fit.terms,
        size * 8,
        bytes as f64 / 1e6,
        t.elapsed().as_secs_f64(),
        // The factored figure resolves about 1e-7 (f64 cancellation): an f32 file's rounding
        // lies below that, so it is bounded rather than printed as an exact 0.
        if fit.rel_rmse < 1e-6 { "below 1e-6".to_string() } else { format!("{:.2e}", fit.rel_rmse) },
        size * 8
    );
    Ok(())
}

/// `btfrig sparse ...`.
#[derive(Debug, Subcommand)]
pub enum SparseCommand {
    /// Choose the captures that keep the basis well conditioned and write them as a plan's
    /// `[sparse]` table (docs/plan-format.md).
    Select(SelectArgs),
    /// Reconstruct the full BTF of a sparse dataset with a basis; writes a model file.
    Reconstruct(ReconstructArgs),
}

/// `btfrig sparse select`.
#[derive(Debug, Args)]
pub struct SelectArgs {
    /// The basis: an FMF model file (rgb or yuv) of a similar material.
    #[arg(long)]
    pub basis: PathBuf,
    /// Captures to choose.
    #[arg(long)]
    pub captures: usize,
    /// A plan to copy: the output is this plan plus the `[sparse]` table (its relative paths
    /// then resolve against the output file's directory).
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Plan file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing file.
    #[arg(long)]
    pub overwrite: bool,
}

/// Writes a plan with the chosen subset.
pub fn select(a: &SelectArgs) -> anyhow::Result<()> {
    let basis = file::read(&a.basis)?;
    if a.out.exists() && !a.overwrite {
        anyhow::bail!("{} already exists: refusing to overwrite it (--overwrite to replace)", a.out.display());
    }
    let sel = sparse::select(&basis, a.captures, Strategy::MaxVolume)?;
    let rnd = sparse::select(&basis, a.captures, Strategy::Random(1))?;
    let mut text = match &a.plan {
        Some(p) => std::fs::read_to_string(p).with_context(|| format!("cannot read plan {}", p.display()))?,
        None => "[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n".into(),
    };
    if !text.ends_with('\n') {
        text.push('\n');
    }
    text.push_str(&sparse_table(&sel, &a.basis));
    std::fs::write(&a.out, &text).with_context(|| format!("cannot write {}", a.out.display()))?;
    let m = basis.layout.n_measured();
    println!(
        "selected  {} of {m} captures ({:.1}%), kappa(M U) per channel {:.1} / {:.1} / {:.1} (random choice: {:.1} / {:.1} / {:.1})",
        sel.pairs.len(),
        100.0 * sel.pairs.len() as f64 / m as f64,
        sel.kappa[0],
        sel.kappa[1],
        sel.kappa[2],
        rnd.kappa[0],
        rnd.kappa[1],
        rnd.kappa[2]
    );
    println!("wrote     {}", a.out.display());
    Ok(())
}

/// The `[sparse]` table of a plan for `sel`.
pub fn sparse_table(sel: &sparse::Selection, basis: &Path) -> String {
    let mut s = String::new();
    s.push_str("\n# Written by `btfrig sparse select`: the captures that keep the basis well conditioned\n");
    s.push_str(&format!(
        "# (basis {}, condition number of M U per channel {:.2} / {:.2} / {:.2}).\n",
        basis.display(),
        sel.kappa[0],
        sel.kappa[1],
        sel.kappa[2]
    ));
    s.push_str("[sparse]\npairs = [\n");
    for chunk in sel.pairs.chunks(8) {
        let line: Vec<String> = chunk.iter().map(|(l, v)| format!("[{l}, {v}]")).collect();
        s.push_str(&format!("  {},\n", line.join(", ")));
    }
    s.push_str("]\n");
    s
}

/// `btfrig sparse reconstruct`.
#[derive(Debug, Args)]
pub struct ReconstructArgs {
    /// The sparse dataset.
    pub dir: PathBuf,
    /// The basis (FMF model file, rgb or yuv).
    #[arg(long)]
    pub basis: PathBuf,
    /// Noise variance of one measured value (regularisation; 0 = plain least squares).
    #[arg(long, default_value_t = 1e-4)]
    pub ridge: f64,
    /// Model file to write (default: `<DIR>.sparse.btfm`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing file.
    #[arg(long)]
    pub overwrite: bool,
}

/// Reconstructs a full model from a sparse dataset.
pub fn reconstruct(a: &ReconstructArgs) -> anyhow::Result<()> {
    let basis = file::read(&a.basis)?;
    let out = a.out.clone().unwrap_or_else(|| default_model_path(&a.dir, "sparse"));
    if out.exists() && !a.overwrite {
        anyhow::bail!("{} already exists: refusing to overwrite it (--overwrite to replace)", out.display());
    }
    let mut src = DatasetSource::open(&a.dir)?;
    let model = sparse::reconstruct(&basis, &mut src, a.ridge)?;
    let fit = btfrig_compress::eval::error_against(&model, &mut src)?.rel_rmse();
    let source = serde_json::json!({"dataset": a.dir.display().to_string(), "basis": a.basis.display().to_string(),
        "ridge": a.ridge, "captures": src.layout().n_measured(), "rel_rmse_vs_dataset": fit});
    let bytes = file::write(&out, &model, source, a.overwrite)?;
    println!(
        "reconstructed {} of {} pairs from {} captures; relative RMSE {fit:.5} at the captured pairs; wrote {} ({:.2} MB)",
        model.layout.n_angular(),
        model.layout.n_angular(),
        src.layout().n_measured(),
        out.display(),
        bytes as f64 / 1e6
    );
    Ok(())
}

/// One line per compression figure, for the run and demo summaries.
pub fn print_streaming(v: &serde_json::Value) {
    for tmp in v["compression_removed_tmp"].as_array().into_iter().flatten() {
        println!(
            "  compression       removed {} (left by a run killed while writing its model)",
            tmp.as_str().unwrap_or("?")
        );
    }
    let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    println!(
        "  compression       {} -> {} ({:.1} : 1, relative RMSE {:.5} against the textures)",
        v["compression_method"].as_str().unwrap_or("?"),
        v["compression_model"].as_str().unwrap_or("?"),
        f("compression_ratio"),
        f("compression_rel_rmse")
    );
    println!(
        "  streaming         {} textures streamed ({} read back), pipeline waited {:.3} s on the sink (queue max {} of {}), \
         pass 1 busy {:.1} s; after the run: {} passes in {:.1} s, builder peak {:.1} MB; process peak RSS {} \
         (whole run, model included)",
        v["compression_streamed"],
        v["compression_from_disk"],
        f("compression_sink_blocked_s"),
        v["compression_sink_max_queue"],
        v["compression_sink_capacity"],
        f("compression_pass1_busy_s"),
        v["compression_passes"],
        f("compression_finish_s"),
        f("compression_builder_peak_bytes") / 1e6,
        v["peak_rss_mib"].as_f64().map_or("n/a (no /proc/self/status)".into(), |m| format!("{m:.0} MiB"))
    );
}
