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

use std::path::{Path, PathBuf};
use std::time::Instant;

use btfrig_bench::compress::{
    bonn, errors, fmf_terms_for, run_setting, setting, simulate, ClusterError, Row, SimBtf, SimOptions, SimSource,
};
use btfrig_compress::eval::ErrorSums;
use btfrig_compress::sparse::{self, Strategy};
use btfrig_compress::{build, ColorModel, Method, Model, ModelParams, Precision};

/// `btfrig bench compress`.
#[derive(Debug, clap::Args)]
pub struct BenchCompressArgs {
    /// Materials (default: corduroy glazed-tile lacquered-wood; sparse acquisition runs on
    /// lacquered-wood).
    #[arg(long, num_args = 1..)]
    pub material: Vec<String>,
    /// Texels per side.
    #[arg(long, default_value_t = 128)]
    pub size: usize,
    /// Point samples per texel axis of the ground truth (the pipeline uses 4 at 128 texels;
    /// 1 renders 16 times faster).
    #[arg(long, default_value_t = 1)]
    pub subsamples: usize,
    /// Keep every k-th Bonn direction for lights and views (1: all 81 x 81).
    #[arg(long, default_value_t = 1)]
    pub every: usize,
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Fewer settings (FMF 8, PCMF 32 x 8, FMF of PCMF's storage, PCMF 32 x 8 in a shared
    /// basis of 32 and the FMF of its storage).
    #[arg(long)]
    pub quick: bool,
    /// Only the acceptance rows: PCMF 32 x 8 (default local-PCA iterations) and the FMF of its
    /// storage, PCMF 32 x 8 in each shared basis and the FMF of its storage (no FMF 8, no
    /// PCMF without iterations; overrides `--quick`'s other rows).
    #[arg(long)]
    pub equal_storage_only: bool,
    /// PCMF 32 x 8 with its cluster bases in a shared angular basis of K terms (a model of its
    /// own, `btfrig compress --method pcmf --shared-basis K`), for each K given, each against
    /// the FMF with the fewest terms of at least its payload; default 32, the full run 32 64.
    #[arg(long, num_args = 1..)]
    pub shared_basis: Vec<usize>,
    /// Skip plain PCMF 32 x 8 (own basis per cluster, 18 passes) and the FMF of its storage:
    /// only the shared-basis rows and their FMFs (with `--equal-storage-only`).
    #[arg(long)]
    pub no_plain_pcmf: bool,
    /// Skip sparse acquisition (which renders a second sample of lacquered-wood).
    #[arg(long)]
    pub no_sparse: bool,
    /// Sparse acquisition: captures used (default: 10 % of the measured ones).
    #[arg(long)]
    pub sparse_captures: Option<usize>,
    /// Also write the first material's measured BTF here as a dataset (for `btfrig compress`,
    /// `dataset export`).
    #[arg(long)]
    pub dataset_out: Option<PathBuf>,
    /// Cache of rendered truths (default: target/bench-cache).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// What `simulate` takes of the arguments (JSON output: no progress lines).
fn sim_options(a: &BenchCompressArgs) -> SimOptions {
    SimOptions { size: a.size, subsamples: a.subsamples, every: a.every, quiet: a.json }
}

fn print_row(r: &Row) {
    println!(
        "{:<15} {:<11} {:<8} {:<10} {:>8.2} {:>7.1} {:>8.1} {:>3} {:>8.1} {:>9.1} {:>10.5} {:>10.5}",
        r.material,
        r.method,
        r.color,
        format!("{}/{}/{}", r.terms[0], r.terms[1], r.terms[2]),
        r.file_bytes as f64 / 1e6,
        r.ratio,
        r.build_s,
        r.passes,
        r.builder_peak_mb,
        r.decode_mtexel_s,
        r.rel_rmse_measured,
        r.rel_rmse_truth
    );
    for (i, st) in r.refine.iter().enumerate() {
        println!(
            "    local PCA on the data, iteration {}: {} texels moved, model vs measured (before f16) {:.5} -> {:.5} \
             before refitting; clusters {}..{} texels",
            i + 1,
            st.moved,
            st.rel_err_before,
            st.rel_err_after,
            st.min_cluster,
            st.max_cluster
        );
    }
    if !r.cluster_errors.is_empty() {
        let ce = &r.cluster_errors;
        let show = |c: &ClusterError| {
            format!("{} texels {:.5}/{:.5} (noise {:.5})", c.texels, c.rel_rmse_measured, c.rel_rmse_truth, c.noise)
        };
        println!(
            "    clusters (vs meas./vs truth): smallest {}; {}; median {}; largest {}",
            show(&ce[0]),
            show(&ce[1.min(ce.len() - 1)]),
            show(&ce[ce.len() / 2]),
            show(&ce[ce.len() - 1])
        );
    }
}

/// Runs the benchmark.
pub fn bench(a: &BenchCompressArgs) -> anyhow::Result<()> {
    anyhow::ensure!((8..=1024).contains(&a.size), "--size {}: allowed 8..=1024 texels", a.size);
    anyhow::ensure!((1..=8).contains(&a.subsamples), "--subsamples {}: allowed 1..=8", a.subsamples);
    anyhow::ensure!((1..=20).contains(&a.every), "--every {}: allowed 1..=20", a.every);
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let cache = a.cache.clone().unwrap_or_else(|| PathBuf::from("target/bench-cache"));
    let materials = if a.material.is_empty() {
        ["corduroy", "glazed-tile", "lacquered-wood"].map(String::from).to_vec()
    } else {
        a.material.clone()
    };
    // PCMF in a shared basis: K = 32 always, the full run also 64 (unless given).
    let shared_basis = match (a.shared_basis.is_empty(), a.quick || a.equal_storage_only) {
        (false, _) => a.shared_basis.clone(),
        (true, true) => vec![32],
        (true, false) => vec![32, 64],
    };
    let mut rows = Vec::new();
    let mut measured_err = Vec::new();
    let mut verdicts = Vec::new();
    let mut verdict_lines: Vec<String> = Vec::new();
    let mut sparse_out = None;
    if !a.json {
        println!(
            "compression benchmark: Bonn {}x{} directions, {}x{} texels, truth {}x{} samples per texel, {} rayon threads",
            bonn(a.every)?.len(),
            bonn(a.every)?.len(),
            a.size,
            a.size,
            a.subsamples,
            a.subsamples,
            rayon::current_num_threads()
        );
    }
    for (mi, name) in materials.iter().enumerate() {
        let spec = crate::material::load(Some(name))?.with_texels(a.size.max(64));
        let btf = simulate(&cfg, &spec, sim_options(a), a.seed, &cache)?;
        let noise = {
            let mut e = ErrorSums::default();
            for r in (0..btf.layout.n_angular()).filter(|&x| btf.layout.measured[x]) {
                e.add(&btf.measured_row(r).expect("m"), &btf.truth_row(r).expect("m"));
            }
            e.rel_rmse()
        };
        measured_err.push(
            serde_json::json!({"material": name, "captures": btf.layout.n_measured(), "measured_vs_truth": noise}),
        );
        if mi == 0 {
            if let Some(dir) = &a.dataset_out {
                let t = Instant::now();
                btfrig_compress::dataset::write_dataset(
                    dir,
                    &btf.layout,
                    &mut |x| btf.measured_row(x).expect("measured"),
                    &cfg.rig.name,
                    &format!("bench compress: simulated measurement of {name}, {} texels, seed {}", a.size, a.seed),
                    true,
                )?;
                if !a.json {
                    println!("dataset   {} written in {:.0} s", dir.display(), t.elapsed().as_secs_f64());
                }
            }
        }
        if !a.json {
            println!();
            println!(
                "{name}: {} captures ({} pairs unreachable), raw {:.1} MB at half precision; measured vs truth: relative RMSE {noise:.5}",
                btf.layout.n_measured(),
                btf.layout.n_angular() - btf.layout.n_measured(),
                btf.raw_bytes() as f64 / 1e6
            );
            println!(
                "{:<15} {:<11} {:<8} {:<10} {:>8} {:>7} {:>8} {:>3} {:>8} {:>9} {:>10} {:>10}",
                "material",
                "method",
                "colour",
                "terms",
                "MB",
                "ratio",
                "build s",
                "ps",
                "peak MB",
                "Mtexel/s",
                "vs meas.",
                "vs truth"
            );
        }
        let mut run = |p: ModelParams| -> anyhow::Result<(Model, Row)> {
            let (m, r) = run_setting(name, &btf, &p)?;
            if !a.json {
                print_row(&r);
            }
            rows.push(r.clone());
            Ok((m, r))
        };
        if !a.equal_storage_only {
            run(setting(Method::Fmf, ColorModel::Rgb, [8; 3]))?;
            // PCMF as k-means in the clustering basis then PCA (no local-PCA iteration on the
            // data), and with the default iterations: the same storage.
            let mut plain = setting(Method::pcmf(32), ColorModel::Rgb, [8; 3]);
            plain.refine_iters = 0;
            run(plain)?;
        }
        if !a.no_plain_pcmf {
            let (pcmf, pcmf_row) = run(setting(Method::pcmf(32), ColorModel::Rgb, [8; 3]))?;
            let k_eq = fmf_terms_for(pcmf.payload_bytes(), &btf.layout, Precision::F16);
            let (_, fmf_row) = run(setting(Method::Fmf, ColorModel::Rgb, [k_eq; 3]))?;
            let wins = pcmf_row.rel_rmse_truth < fmf_row.rel_rmse_truth;
            let what = format!(
                "verdict {name}: PCMF 32 x 8 ({:.2} MB) vs FMF {k_eq} terms ({:.2} MB, the fewest terms with at least \
                 PCMF's payload)",
                pcmf_row.file_bytes as f64 / 1e6,
                fmf_row.file_bytes as f64 / 1e6,
            );
            verdict_lines.push(verdict_line(what, pcmf_row.rel_rmse_truth, fmf_row.rel_rmse_truth, a.json));
            verdicts.push(serde_json::json!({"material": name, "pcmf_rel_rmse_truth": pcmf_row.rel_rmse_truth,
                "fmf_terms": k_eq, "fmf_rel_rmse_truth": fmf_row.rel_rmse_truth,
                "pcmf_file_bytes": pcmf_row.file_bytes, "fmf_file_bytes": fmf_row.file_bytes, "pcmf_wins": wins}));
        }
        for &kk in &shared_basis {
            if kk < 8 || kk > btfrig_compress::build::max_shared_basis(&btf.layout) {
                anyhow::bail!(
                    "--shared-basis {kk}: allowed 8 (the terms per cluster) ..= {}",
                    btfrig_compress::build::max_shared_basis(&btf.layout)
                );
            }
            let (shared, r) = run(setting(Method::pcmf_shared(32, kk), ColorModel::Rgb, [8; 3]))?;
            let payload = shared.payload_bytes();
            // The FMF with the fewest terms whose payload is at least the shared PCMF's (as for
            // plain PCMF above; stricter than the most terms with at most its payload: one more
            // term, 137 kB at 128 x 128 texels).
            let k_w = fmf_terms_for(payload, &btf.layout, Precision::F16);
            let (_, fw) = run(setting(Method::Fmf, ColorModel::Rgb, [k_w; 3]))?;
            let wins = r.rel_rmse_truth < fw.rel_rmse_truth;
            let what = format!(
                "verdict {name}, shared basis {kk}: PCMF 32 x 8 in W{kk} ({:.2} MB payload, {:.2} MB file, built in \
                 {:.0} s) vs FMF {k_w} terms ({:.2} MB payload, the fewest terms with at least its payload)",
                payload as f64 / 1e6,
                r.file_bytes as f64 / 1e6,
                r.build_s,
                fw.payload_bytes as f64 / 1e6,
            );
            verdict_lines.push(verdict_line(what, r.rel_rmse_truth, fw.rel_rmse_truth, a.json));
            verdicts.push(serde_json::json!({"material": name, "shared_basis": kk,
                "pcmf_rel_rmse_truth": r.rel_rmse_truth, "pcmf_payload_bytes": payload, "pcmf_file_bytes": r.file_bytes,
                "pcmf_build_s": r.build_s, "fmf_terms": k_w, "fmf_payload_bytes": fw.payload_bytes,
                "fmf_file_bytes": fw.file_bytes, "fmf_rel_rmse_truth": fw.rel_rmse_truth, "pcmf_wins": wins}));
        }
        if !a.quick && !a.equal_storage_only {
            run(setting(Method::Pvmf, ColorModel::Rgb, [8; 3]))?;
            run(setting(Method::Fmf, ColorModel::Yuv, [32, 16, 16]))?;
            run(setting(Method::Fmf, ColorModel::YlogUv, [32, 16, 16]))?;
            run(setting(Method::pcmf(32), ColorModel::Yuv, [8, 4, 4]))?;
        }
        if name == "lacquered-wood" && !a.no_sparse {
            sparse_out = Some(sparse_bench(a, &cfg, &spec, &btf, &cache)?);
        }
    }
    if a.json {
        println!(
            "{}",
            serde_json::json!({"rows": rows, "measured": measured_err, "verdicts": verdicts, "sparse": sparse_out,
                "peak_rss_mib": btfrig_measurement::peak_rss_mib()})
        );
    } else {
        println!();
        println!("MB: model file; ratio: raw half-float captures / file; ps: passes over the data; peak MB: the builder's sketches;");
        println!("Mtexel/s: decode at random direction pairs (interpolated), all threads; vs meas./vs truth: relative RMSE of the");
        println!("decoded model against the noisy measured textures and the noise-free ground truth, every capture and texel.");
        println!();
        println!("issue 8: does PCMF 32 x 8 beat the FMF of the same storage against the truth?");
        for l in &verdict_lines {
            println!("  {l}");
        }
        println!(
            "process peak RSS {} (the whole benchmark: the in-memory truths, every model and its evaluation)",
            btfrig_measurement::peak_rss_mib().map_or("n/a (no /proc/self/status)".into(), |m| format!("{m:.0} MiB"))
        );
    }
    Ok(())
}

/// Sparse acquisition on lacquered-wood: basis from another sample of the material.
fn sparse_bench(
    a: &BenchCompressArgs,
    cfg: &btfrig_core::config::RigConfig,
    spec: &btfrig_render::material::MaterialSpec,
    test: &SimBtf,
    cache: &Path,
) -> anyhow::Result<serde_json::Value> {
    let mut other = spec.clone();
    other.seed = other.seed.wrapping_add(1);
    let train = simulate(cfg, &other, sim_options(a), a.seed + 1, cache)?;
    let count = a.sparse_captures.unwrap_or(test.layout.n_measured() / 10);
    let mut out = Vec::new();
    if !a.json {
        println!();
        println!(
            "sparse acquisition, lacquered-wood: basis = FMF of a full measurement of ANOTHER sample (material seed {}), \
             captures chosen on it; {count} of {} captures ({:.1} %)",
            other.seed,
            test.layout.n_measured(),
            100.0 * count as f64 / test.layout.n_measured() as f64
        );
        println!(
            "{:<10} {:<11} {:>7} {:>24} {:>10} {:>10}",
            "basis", "choice", "ridge", "kappa(M U) R/G/B", "vs truth", "full meas."
        );
    }
    let full = {
        let mut e = ErrorSums::default();
        for r in (0..test.layout.n_angular()).filter(|&x| test.layout.measured[x]) {
            e.add(&test.measured_row(r).expect("m"), &test.truth_row(r).expect("m"));
        }
        e.rel_rmse()
    };
    for k in [16usize, 32] {
        let (basis, _) = build::<f32>(
            train.layout.clone(),
            &setting(Method::Fmf, ColorModel::Rgb, [k; 3]),
            &mut SimSource { btf: &train, measured: true, only: None },
        )?;
        // The projection of the full measurement onto the basis: denoising, and the floor of
        // any reconstruction with this basis.
        let den = sparse::denoise(&basis, &mut SimSource { btf: test, measured: true, only: None })?;
        let (_, den_t) = errors(&den, test);
        if !a.json {
            println!(
                "{:<10} {:<11} {:>7} {:>24} {:>10.5} {:>10.5}",
                format!("fmf-{k}"),
                "all (denoise)",
                0,
                "-",
                den_t.rel_rmse(),
                full
            );
        }
        out.push(serde_json::json!({"basis_terms": k, "choice": "all", "rel_rmse_truth": den_t.rel_rmse(), "full_measured": full}));
        for (label, strat) in [("max-volume", Strategy::MaxVolume), ("random", Strategy::Random(7))] {
            let sel = sparse::select(&basis, count, strat)?;
            let mut only = vec![false; test.layout.n_angular()];
            for &(l, v) in &sel.pairs {
                only[test.layout.index(l, v)] = true;
            }
            for ridge in [0.0, 1e-4] {
                let rec = sparse::reconstruct(
                    &basis,
                    &mut SimSource { btf: test, measured: true, only: Some(&only) },
                    ridge,
                )?;
                let (_, et) = errors(&rec, test);
                if !a.json {
                    println!(
                        "{:<10} {:<11} {:>7.0e} {:>24} {:>10.5} {:>10.5}",
                        format!("fmf-{k}"),
                        label,
                        ridge,
                        format!("{:.1}/{:.1}/{:.1}", sel.kappa[0], sel.kappa[1], sel.kappa[2]),
                        et.rel_rmse(),
                        full
                    );
                }
                out.push(serde_json::json!({"basis_terms": k, "choice": label, "ridge": ridge, "captures": count,
                    "kappa": sel.kappa, "rel_rmse_truth": et.rel_rmse(), "full_measured": full}));
            }
        }
    }
    Ok(serde_json::Value::Array(out))
}

/// `what`, then both errors against the truth and whether PCMF's is the lower; printed
/// unless `json`.
fn verdict_line(what: String, pcmf_truth: f64, fmf_truth: f64, json: bool) -> String {
    let wins = if pcmf_truth < fmf_truth { "yes" } else { "no" };
    let line = format!("{what}, vs truth {pcmf_truth:.5} vs {fmf_truth:.5}: PCMF beats the equal-storage FMF: {wins}");
    if !json {
        println!("{line}");
    }
    line
}
