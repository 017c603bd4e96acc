//! `btfrig model car` and the CAR rows of `btfrig bench model`: seed 002's probabilistic
//! model (`btfrig_model::car`) over a dataset's textures, with photometric stereo's range
//! map for the bump mapping (docs/material-models.md).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use btfrig_model::car::stats::{distance, stats, StatsDistance};
use btfrig_model::car::{fit, CarBtf, CarInput, CarParams, RangeEnlargement};
use btfrig_model::ps::{photometric_stereo, PsInput, PsMethod, PsParams};
use clap::Args;

use super::{heights, Observations};

/// `btfrig model car`.
#[derive(Debug, Args)]
pub struct CarArgs {
    /// The dataset directory.
    pub dataset: PathBuf,
    /// Output directory (new or empty; nothing is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Size of the synthesised texture, `WxH` texels (default: 4 times the measured size).
    #[arg(long)]
    pub size: Option<String>,
    /// Light direction `THETA,PHI` in degrees (sample frame; default: the first capture's).
    #[arg(long, requires = "view", allow_hyphen_values = true)]
    pub light: Option<String>,
    /// View direction `THETA,PHI` in degrees.
    #[arg(long, requires = "light", allow_hyphen_values = true)]
    pub view: Option<String>,
    /// Sub-spaces of the (light, view) pairs (k-means).
    #[arg(long, default_value_t = 4)]
    pub clusters: usize,
    /// Gaussian-Laplacian pyramid levels.
    #[arg(long, default_value_t = 3)]
    pub levels: usize,
    /// Radius of the causal neighbourhood (1: 4 neighbours, 2: 12).
    #[arg(long, default_value_t = 2)]
    pub radius: usize,
    /// Seed of the clustering and of the synthesis noise.
    #[arg(long, default_value_t = 2)]
    pub seed: u64,
    /// Range map enlargement: car (synthesised, no repetition) or mirror (tiled).
    #[arg(long, default_value = "car")]
    pub range: String,
    /// No range map and no bump mapping: the CAR models the measured textures as they are.
    #[arg(long)]
    pub no_bump: bool,
    /// Print the descriptor as JSON.
    #[arg(long)]
    pub json: bool,
}

fn parse_range(s: &str) -> anyhow::Result<RangeEnlargement> {
    match s {
        "car" => Ok(RangeEnlargement::Car),
        "mirror" => Ok(RangeEnlargement::Mirror),
        other => anyhow::bail!("--range {other:?}: allowed: car, mirror"),
    }
}

fn parse_size(s: &str) -> anyhow::Result<(usize, usize)> {
    let bad = || anyhow::anyhow!("--size {s:?}: expected WxH with W and H from 1 to 16384 texels, e.g. 256x256");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (usize, usize) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    anyhow::ensure!((1..=16384).contains(&w) && (1..=16384).contains(&h), bad());
    Ok((w, h))
}

fn parse_direction(flag: &str, s: &str) -> anyhow::Result<[f64; 3]> {
    let bad = || anyhow::anyhow!("--{flag} {s:?}: expected THETA,PHI in degrees with 0 <= THETA < 90, e.g. 30,45");
    let (t, p) = s.split_once(',').ok_or_else(bad)?;
    let (t, p): (f64, f64) = (t.trim().parse().map_err(|_| bad())?, p.trim().parse().map_err(|_| bad())?);
    anyhow::ensure!((0.0..90.0).contains(&t) && p.is_finite(), bad());
    let v = btfrig_core::Direction::from_degrees(t, p).to_vector();
    Ok([v.x, v.y, v.z])
}

/// The range map of photometric stereo (robust) on the captures `use_idx` of `obs`.
fn range_map(obs: &Observations, use_idx: &[usize]) -> anyhow::Result<Vec<f64>> {
    let (w, h) = (obs.source.layout().width, obs.source.layout().height);
    let refs: Vec<&[[f32; 3]]> = use_idx.iter().map(|&i| obs.images[i].as_slice()).collect();
    let lights: Vec<[f64; 3]> = use_idx.iter().map(|&i| obs.lights[i]).collect();
    let input = PsInput { what: &obs.what, width: w, height: h, lights: &lights, images: &refs };
    let map = photometric_stereo(&input, &PsParams::new(PsMethod::Robust))?;
    Ok(heights(&map, obs.texel_m())?.h)
}

/// Fits the model on the captures `use_idx`.
fn fit_on(obs: &Observations, use_idx: &[usize], p: &CarParams, bump: bool) -> anyhow::Result<CarBtf> {
    let layout = obs.source.layout();
    let hm = if bump { Some(range_map(obs, use_idx)?) } else { None };
    let refs: Vec<&[[f32; 3]]> = use_idx.iter().map(|&i| obs.images[i].as_slice()).collect();
    let lights: Vec<[f64; 3]> = use_idx.iter().map(|&i| obs.lights[i]).collect();
    let views: Vec<[f64; 3]> = use_idx.iter().map(|&i| obs.views[i]).collect();
    let input = CarInput {
        what: &obs.what,
        width: layout.width,
        height: layout.height,
        lights: &lights,
        views: &views,
        images: &refs,
        heights: hm.as_deref(),
        texel_m: obs.texel_m(),
    };
    Ok(fit(&input, p)?)
}

/// The display scale of a texture: its 99th-percentile channel value to 0.85.
fn display_scale(img: &[[f32; 3]]) -> f32 {
    let mut v: Vec<f32> = img.iter().map(|p| p[0].max(p[1]).max(p[2])).collect();
    v.sort_by(f32::total_cmp);
    let p99 = v.get(v.len() * 99 / 100).copied().unwrap_or(1.0);
    if p99 > 0.0 {
        0.85 / p99
    } else {
        1.0
    }
}

fn write_png(path: &Path, w: usize, h: usize, img: &[[f32; 3]], scale: f32) -> anyhow::Result<()> {
    btfrig_imageio::write_srgb8_png(path, w, h, &btfrig_imageio::linear_to_srgb8(img, scale))
        .with_context(|| format!("cannot write {}", path.display()))
}

/// `btfrig model car`.
pub fn model_car(a: &CarArgs) -> anyhow::Result<()> {
    let range = parse_range(&a.range)?;
    let size = a.size.as_deref().map(parse_size).transpose()?;
    let pair = match (&a.light, &a.view) {
        (Some(l), Some(v)) => Some((parse_direction("light", l)?, parse_direction("view", v)?)),
        _ => None,
    };
    let obs = Observations::read(&a.dataset, super::ViewSelection::default())?;
    let (mw, mh) = (obs.source.layout().width, obs.source.layout().height);
    let (w, h) = size.unwrap_or((4 * mw, 4 * mh));
    let (l, v) = pair.unwrap_or((obs.lights[0], obs.views[0]));
    let params = CarParams { clusters: a.clusters, levels: a.levels, radius: a.radius, seed: a.seed, range };
    let all: Vec<usize> = (0..obs.images.len()).collect();
    let t = Instant::now();
    let model = fit_on(&obs, &all, &params, !a.no_bump)?;
    let fit_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let syn = model.synthesise(&l, &v, w, h, a.seed)?;
    let synth_s = t.elapsed().as_secs_f64();
    let out = crate::captures_cmd::prepare_output(Some(a.out.clone()), "btfrig-model-car")?;
    btfrig_imageio::write_rgb_exr(&out.join("texture.exr"), w, h, &syn.texture)?;
    let measured = &obs.images[syn.nearest_pair];
    let scale = display_scale(measured);
    write_png(&out.join("texture.png"), w, h, &syn.texture, scale)?;
    write_png(&out.join("measured.png"), mw, mh, measured, scale)?;
    // Side by side at one texel scale and one display scale, for the eye.
    let (cw, ch) = (mw + 8 + w, mh.max(h));
    let mut canvas = vec![[1.0 / scale; 3]; cw * ch];
    for y in 0..ch {
        for x in 0..cw {
            if x < mw && y < mh {
                canvas[y * cw + x] = measured[y * mw + x];
            } else if x >= mw + 8 && y < h {
                canvas[y * cw + x] = syn.texture[y * w + x - mw - 8];
            }
        }
    }
    write_png(&out.join("comparison.png"), cw, ch, &canvas, scale)?;
    if let Some(hm) = model.heights(w, h, a.seed)? {
        super::write_y_exr(&out.join("height.exr"), w, h, "height", hm.iter().map(|v| *v as f32).collect())?;
    }
    let d = distance(&stats(w, h, &syn.texture), &stats(mw, mh, measured));
    let deg = |d: &[f64; 3]| {
        let t = d[2].clamp(-1.0, 1.0).acos().to_degrees();
        [t, d[1].atan2(d[0]).to_degrees().rem_euclid(360.0)]
    };
    let desc = serde_json::json!({
        "format": "btfrig-car-model",
        "version": 1,
        "source": { "dataset": a.dataset.display().to_string(), "manifest_plan_hash": obs.source.manifest().plan.hash, "captures": obs.images.len() },
        "synthesised": {
            "width": w, "height": h, "seed": a.seed,
            "light_deg": deg(&l), "view_deg": deg(&v),
            "subspace": syn.subspace, "nearest_pair": syn.nearest_pair,
            "files": { "texture": "texture.exr", "preview": "texture.png", "measured_preview": "measured.png", "comparison": "comparison.png", "height": if model.range.is_some() { "height.exr" } else { "" } },
            "png_scale": scale,
            "stats_vs_nearest_measured": d,
            "seconds": synth_s,
            "megapixels_per_s": (w * h) as f64 / 1e6 / synth_s.max(1e-9),
        },
        "parameter_bytes": model.parameter_bytes(),
        "range_bytes": model.range_bytes(),
        "fit_s": fit_s,
        "model": model,
    });
    let text = super::write_descriptor(&out, &desc)?;
    if a.json {
        println!("{text}");
    } else {
        println!(
            "btfrig model car: {} sub-space(s) from {} captures ({mw} x {mh}), {} + {} bytes (CAR + range map), fit {fit_s:.2} s",
            model.subspaces.len(),
            obs.images.len(),
            model.parameter_bytes(),
            model.range_bytes()
        );
        println!(
            "  synthesised {w} x {h} for light {:.1?}, view {:.1?} (sub-space {}, nearest capture {}) in {synth_s:.3} s, {:.2} MP/s",
            deg(&l),
            deg(&v),
            syn.subspace,
            syn.nearest_pair,
            (w * h) as f64 / 1e6 / synth_s.max(1e-9)
        );
        print_distance("  against the nearest measured texture:", &d);
        println!("  texture          {}", out.display());
    }
    Ok(())
}

fn print_distance(label: &str, d: &StatsDistance) {
    println!(
        "{label} mean {:.3} (relative), variance x{:.2}, colour correlation {:.3}, ACF RMS {:.3}, EMD {:.3} (of the std)",
        d.mean_rel,
        d.worst_variance_factor(),
        d.correlation_diff,
        d.acf_rms,
        d.emd_rel
    );
}

/// One row of `bench model`'s CAR table: means over the held-out captures.
#[derive(Debug, serde::Serialize)]
pub(super) struct CarRow {
    material: String,
    model: String,
    held_out: usize,
    mean_rel: f64,
    variance_factor: f64,
    correlation_diff: f64,
    acf_rms: f64,
    emd_rel: f64,
    /// Parameter bytes (CAR), and the range map's.
    bytes: usize,
    range_bytes: usize,
    fit_s: f64,
    /// Synthesis speed at [`SPEED_SIZE`] squared (colour texture with its bump mapping).
    megapixels_per_s: f64,
}

/// Side of the textures timed for the speed, as seed 002 times its 512 x 512 sub-space images
/// (at the demo's 64 x 64 texels a 4x texture is mostly burn-in at the coarse levels).
const SPEED_SIZE: usize = 512;

/// Every 5th capture (from the 3rd) is held out of the fit.
fn held_out_split(n: usize) -> (Vec<usize>, Vec<usize>) {
    (0..n).partition(|i| i % 5 != 2)
}

/// CAR statistics at held-out captures: the model is fitted on the other captures (range map
/// included), each held-out pair is synthesised at the measured size and its statistics are
/// compared with the measured texture's; "nearest measured" is the nearest fitted pair's own
/// texture, the floor that neighbouring measurements set.
pub(super) fn bench_rows(obs: &Observations, material: &str, rows: &mut Vec<CarRow>) -> anyhow::Result<()> {
    let (train, test) = held_out_split(obs.images.len());
    anyhow::ensure!(
        !test.is_empty() && !train.is_empty(),
        "{}: too few captures to hold some out (5 or more needed)",
        obs.what
    );
    let (w, h) = (obs.source.layout().width, obs.source.layout().height);
    // Means over the held-out captures; the sizes, times and speed as given.
    let row = |model: &str, ds: &[StatsDistance], bytes: usize, range_bytes: usize, fit_s: f64, mps: f64| {
        let n = ds.len() as f64;
        let avg = |f: &dyn Fn(&StatsDistance) -> f64| ds.iter().map(f).sum::<f64>() / n;
        CarRow {
            material: material.into(),
            model: model.into(),
            held_out: ds.len(),
            mean_rel: avg(&|d| d.mean_rel),
            variance_factor: avg(&|d| d.worst_variance_factor()),
            correlation_diff: avg(&|d| d.correlation_diff),
            acf_rms: avg(&|d| d.acf_rms),
            emd_rel: avg(&|d| d.emd_rel),
            bytes,
            range_bytes,
            fit_s,
            megapixels_per_s: mps,
        }
    };
    // The default, its range-map alternatives, one pyramid level, the smallest neighbourhood.
    let variants = [
        ("car L3 r2 (range: car)", RangeEnlargement::Car, true, 3, 2),
        ("car L3 r2 (range: mirror)", RangeEnlargement::Mirror, true, 3, 2),
        ("car L3 r2 (no bump)", RangeEnlargement::Car, false, 3, 2),
        ("car L1 r2 (range: car)", RangeEnlargement::Car, true, 1, 2),
        ("car L3 r1 (range: car)", RangeEnlargement::Car, true, 3, 1),
    ];
    let mut nearest = Vec::new();
    for (name, range, bump, levels, radius) in variants {
        let params = CarParams { range, levels, radius, ..CarParams::default() };
        let t = Instant::now();
        let model = fit_on(obs, &train, &params, bump)?;
        let fit_s = t.elapsed().as_secs_f64();
        let mut ds = Vec::new();
        let mut synth_s = 0.0;
        for (k, &i) in test.iter().enumerate() {
            let measured = stats(w, h, &obs.images[i]);
            let syn = model.synthesise(&obs.lights[i], &obs.views[i], w, h, k as u64)?;
            ds.push(distance(&stats(w, h, &syn.texture), &measured));
            if nearest.len() < test.len() {
                nearest.push(distance(&stats(w, h, &obs.images[train[syn.nearest_pair]]), &measured));
            }
            let t = Instant::now();
            model.synthesise(&obs.lights[i], &obs.views[i], SPEED_SIZE, SPEED_SIZE, k as u64)?;
            synth_s += t.elapsed().as_secs_f64();
        }
        let mps = (SPEED_SIZE * SPEED_SIZE * test.len()) as f64 / 1e6 / synth_s.max(1e-9);
        rows.push(row(name, &ds, model.parameter_bytes(), model.range_bytes(), fit_s, mps));
    }
    rows.push(row("nearest measured capture", &nearest, train.len() * w * h * 6, 0, 0.0, 0.0));
    Ok(())
}

/// Prints the CAR table.
pub(super) fn print_rows(rows: &[CarRow]) {
    if rows.is_empty() {
        return;
    }
    println!();
    println!("CAR synthesis (seed 002) at held-out captures: statistics, not pixel error (a synthesis is another");
    println!("realisation of the texture, so pixels do not correspond). Means over the held-out captures of:");
    println!("|mean - measured|/measured, variance factor max(r, 1/r), largest difference of the channels'");
    println!("correlation coefficients, ACF RMS difference (lags 1..8, x and y), EMD / measured std (worst");
    println!("channel each); speed: a {SPEED_SIZE} x {SPEED_SIZE} colour texture with its bump mapping");
    println!(
        "{:<16} {:<26} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>7} {:>8}",
        "material", "model", "held", "mean", "var x", "RGB corr", "ACF", "EMD", "bytes", "range B", "fit s", "MP/s"
    );
    for r in rows {
        println!(
            "{:<16} {:<26} {:>5} {:>8.4} {:>8.3} {:>8.4} {:>8.4} {:>8.4} {:>8} {:>8} {:>7.3} {:>8.2}",
            r.material,
            r.model,
            r.held_out,
            r.mean_rel,
            r.variance_factor,
            r.correlation_diff,
            r.acf_rms,
            r.emd_rel,
            r.bytes,
            r.range_bytes,
            r.fit_s,
            r.megapixels_per_s
        );
    }
}
