//! The measurement behind `btfrig bench color`: each colour-correction model's fit time, apply time (f32 batch, per
//! megapixel) and cross-validated and held-out CIEDE2000, on a (train, test) pair of patch
//! sets. The default sets are spectral and synthetic: the rig's camera sensitivities and lamp
//! (btfrig-render's [`ColourSystem`]) see the 24 ColorChecker spectra plus random mixtures of
//! them (an SG-sized training chart) and other mixtures (held out), with the rig sensor's shot
//! and read noise on patch means. [`run`] takes any (train, test) pair, so measured chart
//! captures can be fed to it later.

use std::time::Instant;

use btfrig_color::{evaluate, select_model, ColorModel, DeltaEStats, FitOptions, ModelKind, Selection, TargetSpace};
use btfrig_render::colour::ColourSystem;
use btfrig_render::spectral::{Spectrum, LEN};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Camera RGB and target colour (linear sRGB, D65) of a set of patches.
#[derive(Debug, Clone, Default)]
pub struct PatchSet {
    /// Camera RGB (full scale 1).
    pub camera: Vec<[f64; 3]>,
    /// Target colour, same scale.
    pub target: Vec<[f64; 3]>,
}

/// One model's measurements.
#[derive(Debug, Clone)]
pub struct ModelResult {
    /// The model.
    pub kind: ModelKind,
    /// Median time of one fit on the training set, ms.
    pub fit_ms: f64,
    /// Median time of applying the model to one megapixel of f32 pixels, single thread, ms.
    pub apply_ms_per_mp: f64,
    /// Condition number of the fit's design matrix.
    pub condition: f64,
    /// Cross-validated ΔE00 on the training set.
    pub cv: DeltaEStats,
    /// ΔE00 on the held-out set.
    pub held_out: DeltaEStats,
}

/// The outcome of [`run`]: per-model results, the failures, and the model cross-validation
/// chose.
#[derive(Debug, Clone)]
pub struct BenchResult {
    /// Models that fitted.
    pub models: Vec<ModelResult>,
    /// Models that could not be fitted or cross-validated, with the reason.
    pub failed: Vec<(ModelKind, String)>,
    /// The chosen model (lowest cross-validated mean ΔE00).
    pub chosen: Option<ModelKind>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Measures every model on (`train`, `test`): selection by `folds`-fold cross-validation on
/// `train`, fit time and f32 apply time (`megapixels` of pixels cycled from the test camera
/// values) as medians of `repeat`, and held-out ΔE00 on `test`.
pub fn run(
    train: &PatchSet,
    test: &PatchSet,
    options: &FitOptions,
    folds: usize,
    megapixels: f64,
    repeat: usize,
) -> BenchResult {
    let space = TargetSpace::LinearSrgb;
    let sel: Selection = select_model(&ModelKind::ALL, &train.camera, &train.target, None, options, space, folds);
    let n_px = ((megapixels * 1e6) as usize).max(1);
    let source: Vec<[f32; 3]> = test.camera.iter().map(|c| c.map(|v| v as f32)).collect();
    let mut models = Vec::new();
    let mut failed = Vec::new();
    for r in &sel.reports {
        let (model, cv) = match (&r.model, &r.cv) {
            (Ok(m), Ok(cv)) => (m, cv),
            (Err(e), _) | (_, Err(e)) => {
                failed.push((r.kind, e.to_string()));
                continue;
            }
        };
        let fit_ms = median(
            (0..repeat)
                .map(|_| {
                    let t = Instant::now();
                    let m = ColorModel::fit(r.kind, &train.camera, &train.target, None, options);
                    let dt = t.elapsed().as_secs_f64() * 1e3;
                    std::hint::black_box(m).ok();
                    dt
                })
                .collect(),
        );
        let mut buf: Vec<[f32; 3]> = (0..n_px).map(|i| source[i % source.len()]).collect();
        let apply_ms_per_mp = median(
            (0..repeat)
                .map(|_| {
                    // Refill so every repetition applies to camera values, not to outputs.
                    for (i, p) in buf.iter_mut().enumerate() {
                        *p = source[i % source.len()];
                    }
                    let t = Instant::now();
                    model.apply_f32(std::hint::black_box(&mut buf));
                    t.elapsed().as_secs_f64() * 1e3 / (n_px as f64 / 1e6)
                })
                .collect(),
        );
        let held_out = match evaluate(model, &test.camera, &test.target, space) {
            Ok(h) => h,
            Err(e) => {
                failed.push((r.kind, e.to_string()));
                continue;
            }
        };
        models.push(ModelResult {
            kind: r.kind,
            fit_ms,
            apply_ms_per_mp,
            condition: model.condition(),
            cv: cv.clone(),
            held_out,
        });
    }
    BenchResult { models, failed, chosen: sel.chosen.map(|i| sel.reports[i].kind) }
}

/// Random plausible reflectances from `base`: alternately additive (convex) and subtractive
/// (weighted geometric) mixtures of 2–3 spectra, each times a brightness in [0.25, 1].
pub fn mixtures(base: &[Spectrum], count: usize, rng: &mut ChaCha8Rng) -> Vec<Spectrum> {
    (0..count)
        .map(|i| {
            let k = rng.gen_range(2..=3);
            let idx: Vec<usize> = (0..k).map(|_| rng.gen_range(0..base.len())).collect();
            let w: Vec<f64> = (0..k).map(|_| rng.gen_range(0.05..1.0)).collect();
            let ws: f64 = w.iter().sum();
            let bright = rng.gen_range(0.25..1.0);
            let mut s = [0.0; LEN];
            for (l, v) in s.iter_mut().enumerate() {
                let mix = if i % 2 == 0 {
                    idx.iter().zip(&w).map(|(&j, wj)| wj / ws * base[j].0[l]).sum::<f64>()
                } else {
                    idx.iter().zip(&w).map(|(&j, wj)| wj / ws * base[j].0[l].max(1e-4).ln()).sum::<f64>().exp()
                };
                *v = bright * mix;
            }
            Spectrum(s)
        })
        .collect()
}

/// Patch means of `spectra` at `exposure` (white reflector: brightest channel = exposure),
/// with shot noise (full well `full_well_e`) and read noise `read_noise_e` averaged over
/// `pixels` pixels; targets scaled alike.
pub fn patch_set(
    sys: &ColourSystem,
    spectra: &[Spectrum],
    exposure: f64,
    full_well_e: f64,
    read_noise_e: f64,
    pixels: f64,
    rng: &mut ChaCha8Rng,
) -> PatchSet {
    let white = sys.camera_white();
    let k = exposure / white.iter().cloned().fold(0.0, f64::max);
    let normal = Normal::new(0.0, 1.0).expect("unit normal");
    let mut set = PatchSet::default();
    for s in spectra {
        let cam = sys.camera_rgb(s).map(|v| {
            let v = v * k;
            let var_e = (v * full_well_e).max(0.0) + read_noise_e * read_noise_e;
            v + normal.sample(rng) * var_e.sqrt() / full_well_e / pixels.sqrt()
        });
        set.camera.push(cam);
        set.target.push(sys.output_rgb(s).map(|v| v * k));
    }
    set
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_render::spectral::colorchecker24;
    use rand::SeedableRng;

    #[test]
    fn synthetic_bench_chooses_a_model_within_the_issue_bounds() {
        let (_, text) = btfrig_core::plan::BUILTIN_RIGS
            .iter()
            .find(|(n, _)| *n == btfrig_core::plan::BUILTIN_RIG)
            .expect("the default rig is embedded");
        let cfg = btfrig_core::config::RigConfig::from_toml(text, "<embedded default rig>").unwrap();
        let sys = ColourSystem::from_config(&cfg.lamp, &cfg.sensor).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let chart = colorchecker24();
        let mut tr = chart.to_vec();
        tr.extend(mixtures(chart, 56, &mut rng));
        let te = mixtures(chart, 60, &mut rng);
        let (fw, rn) = (cfg.sensor.full_well_e, cfg.sensor.read_noise_e);
        let train = patch_set(&sys, &tr, 0.9, fw, rn, 400.0, &mut rng);
        let test = patch_set(&sys, &te, 0.9, fw, rn, 400.0, &mut rng);
        let r = run(&train, &test, &FitOptions::default(), 8, 0.01, 1);
        assert!(r.failed.is_empty(), "{:?}", r.failed);
        assert_eq!(r.models.len(), ModelKind::ALL.len());
        let chosen = r.models.iter().find(|m| Some(m.kind) == r.chosen).unwrap();
        assert!(chosen.held_out.mean < 1.5 && chosen.held_out.max < 4.0, "{chosen:?}");
        assert!(r.models.iter().all(|m| m.fit_ms >= 0.0 && m.apply_ms_per_mp > 0.0));
    }
}
