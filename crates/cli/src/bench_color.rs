//! `btfrig bench color`: each colour-correction model's fit time, apply time (f32 batch, per
//! megapixel) and cross-validated and held-out CIEDE2000, on a (train, test) pair of patch
//! sets. The default sets are spectral and synthetic: the rig's camera sensitivities and lamp
//! (btfrig-render's [`ColourSystem`]) see the 24 ColorChecker spectra plus random mixtures of
//! them (an SG-sized training chart) and other mixtures (held out), with the rig sensor's shot
//! and read noise on patch means. [`run`] takes any (train, test) pair, so measured chart
//! captures can be fed to it later.

use btfrig_bench::color::{mixtures, patch_set, run};
use btfrig_color::{DeltaEStats, FitOptions};
use btfrig_render::colour::ColourSystem;
use btfrig_render::spectral::{colorchecker24, Spectrum};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// `btfrig bench color`.
#[derive(Debug, clap::Args)]
pub struct BenchColorArgs {
    /// Rig config whose lamp spectrum, camera sensitivities and sensor noise are used
    /// (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Training patches: the 24 ColorChecker spectra plus random mixtures up to this count.
    #[arg(long, default_value_t = 140)]
    pub train: usize,
    /// Held-out patches (random mixtures not in the training set).
    #[arg(long, default_value_t = 200)]
    pub test: usize,
    /// Pixels averaged per patch (sets the noise of the patch means).
    #[arg(long, default_value_t = 400.0)]
    pub pixels: f64,
    /// Folds of the cross-validation that selects the model.
    #[arg(long, default_value_t = 10)]
    pub folds: usize,
    /// Ridge parameter of every fit (0 = plain least squares).
    #[arg(long, default_value_t = 0.0)]
    pub ridge: f64,
    /// Megapixels of the f32 batch the apply time is measured on.
    #[arg(long, default_value_t = 4.0)]
    pub megapixels: f64,
    /// Timed repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Seed of the mixtures and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn stats_json(s: &DeltaEStats) -> serde_json::Value {
    serde_json::json!({ "mean": s.mean, "median": s.median, "p95": s.p95, "max": s.max })
}

/// Runs the benchmark on the synthetic spectral sets and prints a table (or JSON).
pub fn bench(a: &BenchColorArgs) -> anyhow::Result<()> {
    anyhow::ensure!((24..=100_000).contains(&a.train), "--train {}: allowed 24..=100000", a.train);
    anyhow::ensure!((1..=100_000).contains(&a.test), "--test {}: allowed 1..=100000", a.test);
    anyhow::ensure!(a.pixels.is_finite() && a.pixels >= 1.0, "--pixels {}: allowed >= 1", a.pixels);
    anyhow::ensure!((2..=a.train).contains(&a.folds), "--folds {}: allowed 2..=train", a.folds);
    anyhow::ensure!(a.megapixels > 0.0 && a.megapixels <= 100.0, "--megapixels {}: allowed (0, 100]", a.megapixels);
    anyhow::ensure!((1..=100).contains(&a.repeat), "--repeat {}: allowed 1..=100", a.repeat);
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let sys = ColourSystem::from_config(&cfg.lamp, &cfg.sensor)?;
    let mut rng = ChaCha8Rng::seed_from_u64(a.seed);
    let chart = colorchecker24();
    let mut train_spectra: Vec<Spectrum> = chart.to_vec();
    train_spectra.extend(mixtures(chart, a.train - 24, &mut rng));
    let test_spectra = mixtures(chart, a.test, &mut rng);
    let (fw, rn) = (cfg.sensor.full_well_e, cfg.sensor.read_noise_e);
    let train = patch_set(&sys, &train_spectra, 0.9, fw, rn, a.pixels, &mut rng);
    let test = patch_set(&sys, &test_spectra, 0.9, fw, rn, a.pixels, &mut rng);
    let options = FitOptions { ridge: a.ridge, ..FitOptions::default() };
    let r = run(&train, &test, &options, a.folds, a.megapixels, a.repeat);
    if a.json {
        let models: Vec<serde_json::Value> = r
            .models
            .iter()
            .map(|m| {
                serde_json::json!({
                    "model": m.kind.name(), "terms": m.kind.terms(), "fit_ms": m.fit_ms,
                    "apply_ms_per_megapixel": m.apply_ms_per_mp, "condition": m.condition,
                    "cv": stats_json(&m.cv), "held_out": stats_json(&m.held_out),
                })
            })
            .collect();
        let failed: Vec<serde_json::Value> =
            r.failed.iter().map(|(k, e)| serde_json::json!({ "model": k.name(), "error": e })).collect();
        let out = serde_json::json!({
            "lamp": cfg.lamp.spectrum, "camera": cfg.sensor.camera_sensitivity,
            "train_patches": train.camera.len(), "test_patches": test.camera.len(),
            "pixels_per_patch": a.pixels, "folds": a.folds, "ridge": a.ridge, "seed": a.seed,
            "chosen": r.chosen.map(|k| k.name()), "models": models, "failed": failed,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "colour benchmark: lamp {}, camera {}, {} training patches ({}-fold CV), {} held out, noise of {} px \
         per patch (full well {fw} e-, read {rn} e-), apply on {} MP f32, 1 thread, median of {}",
        cfg.lamp.spectrum,
        cfg.sensor.camera_sensitivity,
        train.camera.len(),
        a.folds,
        test.camera.len(),
        a.pixels,
        a.megapixels,
        a.repeat
    );
    println!(
        "{:<10} {:>5} {:>9} {:>10} {:>9} | {:>7} {:>7} | {:>7} {:>7} {:>7} {:>7}",
        "model", "terms", "fit (ms)", "ms per MP", "cond", "CV mean", "CV max", "mean", "median", "p95", "max"
    );
    for m in &r.models {
        let mark = if Some(m.kind) == r.chosen { " <- chosen" } else { "" };
        println!(
            "{:<10} {:>5} {:>9.3} {:>10.2} {:>9.2e} | {:>7.3} {:>7.3} | {:>7.3} {:>7.3} {:>7.3} {:>7.3}{mark}",
            m.kind.name(),
            m.kind.terms(),
            m.fit_ms,
            m.apply_ms_per_mp,
            m.condition,
            m.cv.mean,
            m.cv.max,
            m.held_out.mean,
            m.held_out.median,
            m.held_out.p95,
            m.held_out.max
        );
    }
    for (k, e) in &r.failed {
        println!("{:<10} failed: {e}", k.name());
    }
    println!("(CV = cross-validated CIEDE2000 on the training set; mean..max = CIEDE2000 on the held-out patches)");
    Ok(())
}
