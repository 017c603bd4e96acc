//! `btfrig model ps` and `btfrig bench model`: argument handling, reading a dataset's
//! textures and writing the maps, over `btfrig-model` (docs/material-models.md). The truth of
//! `bench model` comes from `btfrig_bench::model::SimSurface` and is read only after the
//! estimates are made.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use btfrig_bench::model::{dataset_region, SimSurface};
use btfrig_compress::dataset::DatasetSource;
use btfrig_model::integrate::{height_sigma, integrate, HeightMap, IntegrateParams};
use btfrig_model::ps::{photometric_stereo, NormalMap, PsInput, PsMethod, PsParams};
use btfrig_model::truth::{surface_errors, SurfaceErrors, SurfaceTruthProbe};
use clap::{Args, Subcommand};
use exr::prelude::*;

mod input_kind;
mod per_view;
pub use per_view::{ptm, scaled_lafortune, PtmArgs};
pub mod car;

/// `btfrig model ...`.
#[derive(Debug, Subcommand)]
pub enum ModelCommand {
    /// Photometric stereo: normal, albedo and height maps (EXR) with their uncertainty and a
    /// JSON descriptor, from a dataset's rectified textures and light directions.
    Ps(PsArgs),
    /// Per-texel Lafortune lobes (K = 1..3) relative to photometric stereo's normals: normal,
    /// albedo and lobe-parameter maps (EXR) and a JSON descriptor.
    Lafortune(LafortuneArgs),
    /// Scaled Lafortune lobes (seed 000): the lobes times a per-texel, per-view scale T(v)
    /// modelling occlusion; the lobe maps plus `view_scale.exr` and a JSON descriptor.
    ScaledLafortune(LobeFitArgs),
    /// A polynomial texture map per view (biquadratic in the projected light direction,
    /// luminance and chroma): coefficient and chroma maps (EXR) and a JSON descriptor.
    Ptm(PtmArgs),
    /// Seed 002's probabilistic model: the (light, view) pairs clustered into sub-spaces, each
    /// one's texture as colour PCA, a Gaussian-Laplacian pyramid and 2D causal autoregressive
    /// models; a texture of any size for any pair, bump-mapped by the range map (EXR, PNG and
    /// the model as JSON).
    Car(car::CarArgs),
}

/// What every lobe fit takes: `btfrig model scaled-lafortune`'s arguments, and
/// `btfrig model lafortune`'s but for `--shadow-maps`.
#[derive(Debug, Args)]
pub struct LobeFitArgs {
    /// The dataset directory.
    pub dataset: PathBuf,
    /// Output directory (new or empty; nothing is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Lobes per texel, 1..=3.
    #[arg(long, default_value_t = 1)]
    pub lobes: usize,
    /// Lobes in the sample frame instead of relative to photometric stereo's normals.
    #[arg(long)]
    pub no_normals: bool,
    /// Print the descriptor as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `btfrig model lafortune`.
#[derive(Debug, Args)]
pub struct LafortuneArgs {
    #[command(flatten)]
    pub fit: LobeFitArgs,
    /// Also fit and write seed 003's self-shadowing (per light direction) and self-occlusion
    /// (per view direction) maps and the per-texel gain on top of the lobes.
    #[arg(long)]
    pub shadow_maps: bool,
}

/// `btfrig model ps`.
#[derive(Debug, Args)]
pub struct PsArgs {
    /// The dataset directory.
    pub dataset: PathBuf,
    /// Output directory (new or empty; nothing is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// robust (shadow threshold, leave-one-light-out start, Tukey IRLS) or least-squares.
    #[arg(long, default_value = "robust")]
    pub method: String,
    /// Robust: the quantile over its views that stands for a repeated light direction.
    #[arg(long, default_value_t = 0.5)]
    pub group_quantile: f64,
    /// Use only this view (the dataset's view id); default: every capture (all views share
    /// the rectified texel grid).
    #[arg(long)]
    pub view: Option<u32>,
    /// Use only the views within this angle of the sample normal (degrees). Oblique views see
    /// each texel's relief shifted by parallax and foreshortened, which costs accuracy
    /// (docs/material-models.md); default: every view.
    #[arg(long, conflicts_with = "view")]
    pub max_view_theta: Option<f64>,
    /// Monte Carlo draws of the height uncertainty.
    #[arg(long, default_value_t = 16)]
    pub draws: usize,
    /// Print the descriptor as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `btfrig bench model`.
#[derive(Debug, Args)]
pub struct BenchModelArgs {
    /// Datasets of the simulated rig (e.g. `btfrig demo --material M --out DIR` for three
    /// materials); the truth is the material their plan names.
    #[arg(required = true, num_args = 1..)]
    pub datasets: Vec<PathBuf>,
    /// Material of every dataset instead of the one its plan names (built-in name).
    #[arg(long)]
    pub material: Option<String>,
    /// Use only this view (the dataset's view id).
    #[arg(long)]
    pub view: Option<u32>,
    /// Use only the views within this angle of the sample normal (degrees); default: every view.
    #[arg(long, conflicts_with = "view")]
    pub max_view_theta: Option<f64>,
    /// Robust: the quantile over its views that stands for a repeated light direction.
    #[arg(long, default_value_t = 0.5)]
    pub group_quantile: f64,
    /// Only photometric stereo (no reflectance models, no FMF/PCMF, no truth textures).
    #[arg(long)]
    pub ps_only: bool,
    /// Of the reflectance models only lafortune-1+normal with and without seed 003's shadow
    /// and occlusion maps (no FMF/PCMF, no more lobes): the cheap check of the maps.
    #[arg(long, conflicts_with = "ps_only")]
    pub sbrdf_only: bool,
    /// Only the CAR synthesis rows (seed 002; statistics at held-out captures).
    #[arg(long, conflicts_with_all = ["ps_only", "sbrdf_only"])]
    pub car_only: bool,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

fn parse_method(s: &str) -> anyhow::Result<PsMethod> {
    match s {
        "robust" => Ok(PsMethod::Robust),
        "least-squares" | "ls" => Ok(PsMethod::LeastSquares),
        other => anyhow::bail!("--method {other:?}: allowed: robust, least-squares"),
    }
}

/// Which captures of a dataset to read: one view, or the views up to an angle from the
/// sample normal, or all.
#[derive(Debug, Clone, Copy, Default)]
struct ViewSelection {
    view: Option<u32>,
    max_theta_deg: Option<f64>,
}

/// A dataset's textures and light directions for photometric stereo.
struct Observations {
    source: DatasetSource,
    what: String,
    lights: Vec<[f64; 3]>,
    views: Vec<[f64; 3]>,
    /// Each capture's (light, view) directions and its layout index.
    pairs: Vec<(btfrig_core::Direction, btfrig_core::Direction, usize)>,
    images: Vec<Vec<[f32; 3]>>,
}

impl Observations {
    fn read(dir: &Path, sel: ViewSelection) -> anyhow::Result<Self> {
        input_kind::ensure_dataset(dir)?;
        let source = DatasetSource::open(dir).with_context(|| format!("dataset {}", dir.display()))?;
        let view = sel.view;
        if let Some(t) = sel.max_theta_deg {
            anyhow::ensure!(
                t.is_finite() && (0.0..=90.0).contains(&t),
                "--max-view-theta {t}: allowed 0 to 90 degrees (the view's angle from the sample normal)"
            );
        }
        let layout = source.layout();
        let (mut steps, mut min_theta_deg) = (Vec::new(), f64::INFINITY);
        for s in source.steps().iter().copied().filter(|s| view.is_none_or(|v| s.view == v)) {
            let (l, v) = source.layout_pair(s);
            let a = layout.index(l as usize, v as usize);
            let (dl, dv) = layout.directions(a);
            let theta_deg = dv.theta.to_degrees();
            min_theta_deg = min_theta_deg.min(theta_deg);
            // A small tolerance: layout directions are stored in degrees and converted.
            if sel.max_theta_deg.is_none_or(|t| theta_deg <= t + 1e-6) {
                steps.push((s, dl, dv, a));
            }
        }
        let what = match (view, sel.max_theta_deg) {
            (Some(v), _) => format!("dataset {}, view {v}", dir.display()),
            (None, Some(t)) => {
                format!("dataset {}, the {} captures of views up to {t} deg", dir.display(), steps.len())
            }
            (None, None) => format!("dataset {}, all {} captures", dir.display(), steps.len()),
        };
        if let Some(v) = view {
            anyhow::ensure!(
                !steps.is_empty(),
                "{what}: no captures of view {v}; the dataset's views with captures: {:?}",
                {
                    let mut v: Vec<u32> = source.steps().iter().map(|s| s.view).collect();
                    v.sort_unstable();
                    v.dedup();
                    v
                }
            );
        }
        if let Some(t) = sel.max_theta_deg {
            anyhow::ensure!(
                !steps.is_empty(),
                "{what}: no captures of a view within {t} deg of the sample normal; the smallest view angle \
                 in the dataset is {min_theta_deg:.2} deg"
            );
        }
        let (mut lights, mut views, mut pairs) = (Vec::new(), Vec::new(), Vec::new());
        for &(_, dl, dv, a) in &steps {
            let (d, e) = (dl.to_vector(), dv.to_vector());
            lights.push([d.x, d.y, d.z]);
            views.push([e.x, e.y, e.z]);
            pairs.push((dl, dv, a));
        }
        let steps: Vec<_> = steps.into_iter().map(|x| x.0).collect();
        use rayon::prelude::*;
        let images = steps.par_iter().map(|s| source.read(*s)).collect::<std::result::Result<Vec<_>, _>>()?;
        Ok(Observations { source, what, lights, views, pairs, images })
    }

    fn input(&self) -> (Vec<&[[f32; 3]]>, usize, usize) {
        let l = self.source.layout();
        (self.images.iter().map(|v| v.as_slice()).collect(), l.width, l.height)
    }

    fn texel_m(&self) -> f64 {
        let m = self.source.manifest();
        m.texture.region.size_m[0] / f64::from(m.texture.width)
    }

    fn normals(&self, params: &PsParams) -> anyhow::Result<(NormalMap, f64)> {
        let (refs, w, h) = self.input();
        let input = PsInput { what: &self.what, width: w, height: h, lights: &self.lights, images: &refs };
        let t = Instant::now();
        let map = photometric_stereo(&input, params)?;
        Ok((map, t.elapsed().as_secs_f64()))
    }
}

/// Slopes of texels steeper than this (`n_z` below it) are clamped.
const MIN_NZ: f64 = 0.1;

/// Integration weight of a texel from its normal's uncertainty: `1 / (1 + (σ / 5°)²)`.
fn weights(map: &NormalMap) -> Vec<f64> {
    map.sigma_deg.iter().map(|s| 1.0 / (1.0 + (f64::from(*s) / 5.0).powi(2))).collect()
}

fn heights(map: &NormalMap, texel_m: f64) -> anyhow::Result<HeightMap> {
    let w = weights(map);
    Ok(integrate(map.width, map.height, &map.gradients(MIN_NZ), Some(&w), texel_m, &IntegrateParams::default())?)
}

fn write_y_exr(path: &Path, width: usize, height: usize, name: &str, data: Vec<f32>) -> anyhow::Result<()> {
    let channel = AnyChannel::new("Y", FlatSamples::F32(data));
    let layer = Layer::new(
        (width, height),
        LayerAttributes::named(name),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(vec![channel])),
    );
    Image::from_layer(layer).write().to_file(path).with_context(|| format!("cannot write {}", path.display()))
}

/// `btfrig model ps`.
pub fn ps(a: &PsArgs) -> anyhow::Result<()> {
    let method = parse_method(&a.method)?;
    let obs = Observations::read(&a.dataset, ViewSelection { view: a.view, max_theta_deg: a.max_view_theta })?;
    let params = PsParams { group_quantile: a.group_quantile, ..PsParams::new(method) };
    let (map, ps_s) = obs.normals(&params)?;
    let texel_m = obs.texel_m();
    let t = Instant::now();
    let hm = heights(&map, texel_m)?;
    let w = weights(&map);
    let sigma = height_sigma(
        map.width,
        map.height,
        &map.gradients(MIN_NZ),
        &map.gradient_sigma(MIN_NZ),
        Some(&w),
        texel_m,
        a.draws,
        1,
    )?;
    let int_s = t.elapsed().as_secs_f64();
    let out = crate::captures_cmd::prepare_output(Some(a.out.clone()), "btfrig-model")?;
    let (w, h) = (map.width, map.height);
    let normal_rgb: Vec<[f32; 3]> = map.normal.iter().map(|n| [n[0] as f32, n[1] as f32, n[2] as f32]).collect();
    btfrig_imageio::write_rgb_exr(&out.join("normal.exr"), w, h, &normal_rgb)?;
    btfrig_imageio::write_rgb_exr(&out.join("albedo.exr"), w, h, &map.albedo)?;
    write_y_exr(&out.join("height.exr"), w, h, "height", hm.h.iter().map(|v| *v as f32).collect())?;
    write_y_exr(&out.join("normal_sigma.exr"), w, h, "normal_sigma_deg", map.sigma_deg.clone())?;
    write_y_exr(&out.join("height_sigma.exr"), w, h, "height_sigma", sigma.iter().map(|v| *v as f32).collect())?;
    let region = dataset_region(obs.source.manifest());
    let (hmin, hmax) = hm.h.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, u), v| (l.min(*v), u.max(*v)));
    let mean_sigma = map.sigma_deg.iter().map(|s| f64::from(*s)).sum::<f64>() / map.sigma_deg.len() as f64;
    let desc = serde_json::json!({
        "format": "btfrig-material-maps",
        "version": 1,
        "source": { "dataset": a.dataset.display().to_string(), "manifest_plan_hash": obs.source.manifest().plan.hash, "captures": obs.lights.len(), "view": a.view, "max_view_theta_deg": a.max_view_theta },
        "method": method.name(),
        "params": params,
        "width": w, "height": h,
        "region_m": region,
        "texel_m": texel_m,
        "frame": "sample frame: x along texture columns (right), y along -rows (up), z out of the surface; row 0 at the region's +y edge",
        "maps": {
            "normal": { "file": "normal.exr", "channels": ["R", "G", "B"], "meaning": "unit normal (x, y, z) in the sample frame, not colour" },
            "albedo": { "file": "albedo.exr", "channels": ["R", "G", "B"], "meaning": "Lambertian albedo, linear sRGB (rho: a white Lambertian reflector is 1)" },
            "height": { "file": "height.exr", "channels": ["Y"], "unit": "m", "meaning": "height above the mean plane (zero mean), integrated from the normals", "min": hmin, "max": hmax },
            "normal_sigma": { "file": "normal_sigma.exr", "channels": ["Y"], "unit": "deg", "meaning": "standard deviation of the normal's direction" },
            "height_sigma": { "file": "height_sigma.exr", "channels": ["Y"], "unit": "m", "meaning": "standard deviation of the height (Monte Carlo over the normals' uncertainty)", "draws": a.draws },
        },
        "timing_s": { "photometric_stereo": ps_s, "integration_and_uncertainty": int_s },
        "mean_normal_sigma_deg": mean_sigma,
    });
    let text = write_descriptor(&out, &desc)?;
    if a.json {
        println!("{text}");
    } else {
        println!("btfrig model ps: {} ({}), {} x {} texels", obs.what, method.name(), w, h);
        println!("  normals          mean predicted sigma {mean_sigma:.2} deg, {ps_s:.2} s");
        println!(
            "  height           {:.3} .. {:.3} mm, {} CG iterations, {int_s:.2} s with uncertainty",
            hmin * 1e3,
            hmax * 1e3,
            hm.iterations
        );
        println!("  maps             {}", out.display());
    }
    Ok(())
}

/// `btfrig model lafortune`.
pub fn lafortune(args: &LafortuneArgs) -> anyhow::Result<()> {
    let (a, shadow_maps) = (&args.fit, args.shadow_maps);
    use btfrig_model::lafortune::{fit, BtfInput, LafortuneParams, ALBEDO_BOUNDS, LOBE_BOUNDS};
    let obs = Observations::read(&a.dataset, ViewSelection::default())?;
    let (refs, w, h) = obs.input();
    let normals = if a.no_normals {
        None
    } else {
        let input = PsInput { what: &obs.what, width: w, height: h, lights: &obs.lights, images: &refs };
        Some(photometric_stereo(&input, &PsParams::new(PsMethod::Robust))?.normal)
    };
    let input =
        BtfInput { texels: w * h, lights: &obs.lights, views: &obs.views, images: &refs, normals: normals.as_deref() };
    let t = Instant::now();
    let map = fit(&input, &LafortuneParams::new(a.lobes))?;
    let fit_s = t.elapsed().as_secs_f64();
    let mut sums = Sums::default();
    for (i, (l, v)) in obs.lights.iter().zip(&obs.views).enumerate() {
        sums.add(&map.texture(l, v), &obs.images[i]);
    }
    let out = crate::captures_cmd::prepare_output(Some(a.out.clone()), "btfrig-lafortune")?;
    let mut files = lobe_maps(&out, w, h, &map)?;
    let mut rel = sums.rel();
    let mut shadow_desc = serde_json::Value::Null;
    if shadow_maps {
        use btfrig_model::sbrdf::{fit as fit_maps, ShadowInput, ShadowParams};
        let base: Vec<Vec<[f32; 3]>> = obs.lights.iter().zip(&obs.views).map(|(l, v)| map.texture(l, v)).collect();
        let base_refs: Vec<&[[f32; 3]]> = base.iter().map(|v| v.as_slice()).collect();
        let input =
            ShadowInput { texels: w * h, lights: &obs.lights, views: &obs.views, images: &refs, base: &base_refs };
        let maps = fit_maps(&input, &ShadowParams::default())?;
        let mut with_maps = Sums::default();
        for (i, (l, v)) in obs.lights.iter().zip(&obs.views).enumerate() {
            with_maps.add(&maps.apply(l, v, &base[i]), &obs.images[i]);
        }
        let (nl, nv) = (maps.light_dirs.len(), maps.view_dirs.len());
        btfrig_imageio::write_rgb_exr(&out.join("shadow.exr"), w, h * nl, &stack(&maps.shadow, w * h, nl))?;
        btfrig_imageio::write_rgb_exr(&out.join("occlusion.exr"), w, h * nv, &stack(&maps.occlusion, w * h, nv))?;
        let gain: Vec<[f32; 3]> = maps.gain.iter().map(|&g| [g; 3]).collect();
        btfrig_imageio::write_rgb_exr(&out.join("gain.exr"), w, h, &gain)?;
        files.insert("shadow".into(), serde_json::json!({ "file": "shadow.exr", "channels": ["R"], "meaning": "self-shadowing factor S in [0, 1]; light direction j (see light_dirs) is rows j*height .. (j+1)*height" }));
        files.insert("occlusion".into(), serde_json::json!({ "file": "occlusion.exr", "channels": ["R"], "meaning": "self-occlusion factor O in [0, 1]; view direction j (see view_dirs) is rows j*height .. (j+1)*height" }));
        files.insert("gain".into(), serde_json::json!({ "file": "gain.exr", "channels": ["R"], "meaning": "per-texel gain g multiplying the lobe model" }));
        shadow_desc = serde_json::json!({
            "formula": "I_c(l, v) = g * S(l) * O(v) * lafortune_c(l, v), S and O at the nearest stored direction",
            "light_dirs": maps.light_dirs,
            "view_dirs": maps.view_dirs,
            "rel_rmse_data_without": rel,
        });
        rel = with_maps.rel();
    }
    let desc = serde_json::json!({
        "format": "btfrig-material-maps",
        "version": 1,
        "model": "lafortune",
        "formula": "I_c(l, v) = l_z (rho_c + sum_k max(0, C_xy,k (l_x v_x + l_y v_y) + C_z,k l_z v_z)^n_k), l and v in the texel's frame (normal map) or the sample frame",
        "lobes": a.lobes,
        "relative_to_normals": normals.is_some(),
        "bounds": { "albedo": ALBEDO_BOUNDS, "lobe": LOBE_BOUNDS },
        "source": { "dataset": a.dataset.display().to_string(), "manifest_plan_hash": obs.source.manifest().plan.hash, "captures": obs.lights.len() },
        "width": w, "height": h,
        "region_m": dataset_region(obs.source.manifest()),
        "maps": files,
        "shadow_occlusion": shadow_desc,
        "rel_rmse_data": rel,
        "fit_s": fit_s,
    });
    let text = write_descriptor(&out, &desc)?;
    if a.json {
        println!("{text}");
    } else {
        println!("btfrig model lafortune: {} lobe(s), {} x {} texels, relative RMSE {rel:.4} against the {} captures, {fit_s:.2} s", a.lobes, w, h, obs.lights.len());
        println!("  maps             {}", out.display());
    }
    Ok(())
}

/// Writes `desc` as `out/model.json`; its text.
fn write_descriptor(out: &Path, desc: &serde_json::Value) -> anyhow::Result<String> {
    let text = serde_json::to_string_pretty(desc)?;
    std::fs::write(out.join("model.json"), format!("{text}\n"))
        .with_context(|| format!("cannot write {}", out.join("model.json").display()))?;
    Ok(text)
}

/// Stacked maps of per-texel, per-direction factors (`f` texel-major, `dirs` per texel):
/// direction j occupies rows j*h .. (j+1)*h; grey in R = G = B.
fn stack(f: &[f32], texels: usize, dirs: usize) -> Vec<[f32; 3]> {
    (0..dirs).flat_map(|j| (0..texels).map(move |t| [f[t * dirs + j]; 3])).collect()
}

/// Writes a Lafortune map's albedo, normal (if any) and lobe maps into `out`; their
/// descriptor entries.
fn lobe_maps(
    out: &Path,
    w: usize,
    h: usize,
    map: &btfrig_model::lafortune::LafortuneMap,
) -> anyhow::Result<serde_json::Map<String, serde_json::Value>> {
    btfrig_imageio::write_rgb_exr(&out.join("albedo.exr"), w, h, &map.albedo)?;
    let mut files = serde_json::Map::new();
    files.insert("albedo".into(), serde_json::json!({ "file": "albedo.exr", "channels": ["R", "G", "B"], "meaning": "diffuse albedo rho, linear sRGB" }));
    if let Some(n) = &map.normal {
        let rgb: Vec<[f32; 3]> = n.iter().map(|n| [n[0] as f32, n[1] as f32, n[2] as f32]).collect();
        btfrig_imageio::write_rgb_exr(&out.join("normal.exr"), w, h, &rgb)?;
        files.insert("normal".into(), serde_json::json!({ "file": "normal.exr", "channels": ["R", "G", "B"], "meaning": "unit normal (x, y, z), sample frame; the lobes' frame" }));
    }
    for k in 0..map.lobes {
        let p: Vec<[f32; 3]> = (0..w * h)
            .map(|t| {
                let l = map.lobe[t * map.lobes + k];
                [l.cxy as f32, l.cz as f32, l.n as f32]
            })
            .collect();
        let name = format!("lobe{}.exr", k + 1);
        btfrig_imageio::write_rgb_exr(&out.join(&name), w, h, &p)?;
        files.insert(format!("lobe{}", k + 1), serde_json::json!({ "file": name, "channels": ["R", "G", "B"], "meaning": "lobe parameters: R = C_xy, G = C_z, B = exponent n (not colour)" }));
    }
    Ok(files)
}

/// One row of `bench model`'s photometric-stereo table.
#[derive(Debug, serde::Serialize)]
struct PsRow {
    dataset: String,
    material: String,
    captures: usize,
    method: &'static str,
    errors: SurfaceErrors,
    fit_s: f64,
}

/// One row of `bench model`'s reflectance table.
#[derive(Debug, serde::Serialize)]
struct FitRow {
    material: String,
    model: String,
    /// Stored bytes (half floats for the per-texel models, the model file for FMF/PCMF).
    bytes: usize,
    /// Relative RMSE against the measured textures.
    rel_rmse_data: f64,
    /// Relative RMSE against the noise-free truth (`None` without one).
    rel_rmse_truth: Option<f64>,
    fit_s: f64,
    eval_s: f64,
}

/// Sums of squared differences and of squared references.
#[derive(Default, Clone, Copy)]
struct Sums {
    diff: f64,
    norm: f64,
}

impl Sums {
    fn add(&mut self, a: &[[f32; 3]], b: &[[f32; 3]]) {
        for (p, q) in a.iter().zip(b) {
            for c in 0..3 {
                self.diff += (f64::from(p[c]) - f64::from(q[c])).powi(2);
                self.norm += f64::from(q[c]).powi(2);
            }
        }
    }
    fn rel(&self) -> f64 {
        (self.diff / self.norm.max(1e-300)).sqrt()
    }
}

fn score(decoded: &[Vec<[f32; 3]>], obs: &Observations, truth: Option<&Vec<Vec<[f32; 3]>>>) -> (f64, Option<f64>) {
    let mut d = Sums::default();
    let mut t = Sums::default();
    for (i, m) in decoded.iter().enumerate() {
        d.add(m, &obs.images[i]);
        if let Some(tr) = truth {
            t.add(m, &tr[i]);
        }
    }
    (d.rel(), truth.map(|_| t.rel()))
}

fn reflectance_rows(
    obs: &mut Observations,
    material: &str,
    sbrdf_only: bool,
    rows: &mut Vec<FitRow>,
) -> anyhow::Result<()> {
    use btfrig_model::lafortune::{fit, BtfInput, LafortuneParams};
    let pairs: Vec<_> = obs.pairs.iter().map(|p| (p.0, p.1)).collect();
    let truth = btfrig_bench::model::truth_textures(obs.source.manifest(), material, &pairs)?;
    let texels = obs.source.layout().texels();
    // The data itself against the truth: the floor every model is measured above.
    let (_, data_truth) = score(&obs.images, obs, truth.as_ref());
    rows.push(FitRow {
        material: material.into(),
        model: "measured data".into(),
        bytes: obs.images.len() * texels * 6,
        rel_rmse_data: 0.0,
        rel_rmse_truth: data_truth,
        fit_s: 0.0,
        eval_s: 0.0,
    });
    // The lobes relative to photometric stereo's normals (robust): normal mapping.
    let (w, h) = (obs.source.layout().width, obs.source.layout().height);
    let (refs, _, _) = obs.input();
    let ps_in = PsInput { what: &obs.what, width: w, height: h, lights: &obs.lights, images: &refs };
    let normals = photometric_stereo(&ps_in, &PsParams::new(PsMethod::Robust))?.normal;
    drop(refs);
    let configs: &[(usize, bool)] =
        if sbrdf_only { &[(1, true)] } else { &[(1, false), (1, true), (2, true), (3, true)] };
    for &(k, with_normals) in configs {
        let refs: Vec<&[[f32; 3]]> = obs.images.iter().map(|v| v.as_slice()).collect();
        let input = BtfInput {
            texels,
            lights: &obs.lights,
            views: &obs.views,
            images: &refs,
            normals: with_normals.then_some(normals.as_slice()),
        };
        let t = Instant::now();
        let map = fit(&input, &LafortuneParams::new(k))?;
        let fit_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let decoded: Vec<Vec<[f32; 3]>> = obs.lights.iter().zip(&obs.views).map(|(l, v)| map.texture(l, v)).collect();
        let eval_s = t.elapsed().as_secs_f64();
        let (e_data, e_truth) = score(&decoded, obs, truth.as_ref());
        // Half floats; a normal is 2 of them (z follows).
        let bytes = texels * (map.values_per_texel() + if with_normals { 2 } else { 0 }) * 2;
        rows.push(FitRow {
            material: material.into(),
            model: format!("lafortune-{k}{}", if with_normals { "+normal" } else { "" }),
            bytes,
            rel_rmse_data: e_data,
            rel_rmse_truth: e_truth,
            fit_s,
            eval_s,
        });
        if !with_normals {
            continue;
        }
        // Seed 003: the SBRDF times self-shadowing (per light) and self-occlusion (per view) maps.
        {
            use btfrig_model::sbrdf::{fit as fit_maps, ShadowInput, ShadowParams};
            let base: Vec<&[[f32; 3]]> = decoded.iter().map(|v| v.as_slice()).collect();
            let input = ShadowInput { texels, lights: &obs.lights, views: &obs.views, images: &refs, base: &base };
            let t = Instant::now();
            let maps = fit_maps(&input, &ShadowParams::default())?;
            let maps_fit_s = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let combined: Vec<Vec<[f32; 3]>> =
                obs.lights.iter().zip(&obs.views).map(|(l, v)| maps.apply(l, v, &map.texture(l, v))).collect();
            let maps_eval_s = t.elapsed().as_secs_f64();
            let (d2, t2) = score(&combined, obs, truth.as_ref());
            rows.push(FitRow {
                material: material.into(),
                // One byte per factor in [0, 1], a half float for the gain.
                model: format!(
                    "lafortune-{k}+normal+shadow/occl ({}+{} dirs)",
                    maps.light_dirs.len(),
                    maps.view_dirs.len()
                ),
                bytes: bytes + texels * (maps.values_per_texel() + 1),
                rel_rmse_data: d2,
                rel_rmse_truth: t2,
                fit_s: fit_s + maps_fit_s,
                eval_s: maps_eval_s,
            });
        }
        if sbrdf_only {
            continue;
        }
        linear_rows(obs, material, bytes, &format!("lafortune-{k}"), truth.as_ref(), rows)?;
    }
    if !sbrdf_only {
        per_view::rows(obs, material, truth.as_ref(), &normals, rows)?;
    }
    Ok(())
}

/// FMF and PCMF (8 clusters) with the fewest terms of at least `bytes`, labelled `~like`.
fn linear_rows(
    obs: &mut Observations,
    material: &str,
    bytes: usize,
    like: &str,
    truth: Option<&Vec<Vec<[f32; 3]>>>,
    rows: &mut Vec<FitRow>,
) -> anyhow::Result<()> {
    use btfrig_compress::{build, file, Method, ModelParams, Precision};
    for pcmf in [false, true] {
        let mut chosen = None;
        for terms in 1..=64usize {
            let mut p =
                ModelParams::new(if pcmf { Method::Pcmf { clusters: 8, shared_basis: None } } else { Method::Fmf });
            p.terms = [terms, terms.div_ceil(2), terms.div_ceil(2)];
            p.precision = Precision::F16;
            let t = Instant::now();
            let Ok((model, _)) = build::<f32>(obs.source.layout().clone(), &p, &mut obs.source) else { break };
            let fit_s = t.elapsed().as_secs_f64();
            let size = file::encode(&model, serde_json::Value::Null).len();
            chosen = Some((model, fit_s, size, terms));
            if size >= bytes {
                break;
            }
        }
        let Some((model, fit_s, size, terms)) = chosen else { continue };
        let t = Instant::now();
        let decoded: Vec<Vec<[f32; 3]>> = obs.pairs.iter().map(|p| model.texture(p.2)).collect();
        let eval_s = t.elapsed().as_secs_f64();
        let (e_data, e_truth) = score(&decoded, obs, truth);
        rows.push(FitRow {
            material: material.into(),
            model: format!("{}-{terms} (~{like})", if pcmf { "pcmf-8" } else { "fmf" }),
            bytes: size,
            rel_rmse_data: e_data,
            rel_rmse_truth: e_truth,
            fit_s,
            eval_s,
        });
    }
    Ok(())
}

/// `btfrig bench model`.
pub fn bench(a: &BenchModelArgs) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    let mut fits = Vec::new();
    let mut cars = Vec::new();
    for d in &a.datasets {
        let mut obs = Observations::read(d, ViewSelection { view: a.view, max_theta_deg: a.max_view_theta })?;
        let mut estimates = Vec::new();
        for method in [PsMethod::LeastSquares, PsMethod::Robust] {
            let (map, fit_s) = obs.normals(&PsParams { group_quantile: a.group_quantile, ..PsParams::new(method) })?;
            let hm = heights(&map, obs.texel_m())?;
            estimates.push((method, map, hm, fit_s));
        }
        // The truth, only now that the estimates are made.
        let probe = SimSurface::for_dataset(obs.source.manifest(), a.material.as_deref())?;
        let l = obs.source.layout();
        let truth = probe.surface(dataset_region(obs.source.manifest()), l.width, l.height);
        for (method, map, hm, fit_s) in estimates {
            rows.push(PsRow {
                dataset: d.display().to_string(),
                material: probe.material.clone(),
                captures: obs.lights.len(),
                method: method.name(),
                errors: surface_errors(&map.normal, Some(&hm.h), &map.sigma_deg, &truth),
                fit_s,
            });
        }
        if !a.ps_only && !a.car_only {
            reflectance_rows(&mut obs, &probe.material, a.sbrdf_only, &mut fits)?;
        }
        if !a.ps_only && !a.sbrdf_only {
            car::bench_rows(&obs, &probe.material, &mut cars)?;
        }
    }
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "photometric_stereo": rows, "reflectance": fits, "car": cars })
            )?
        );
        return Ok(());
    }
    println!(
        "photometric stereo against the simulator's true surface (per texel: normalised mean normal, mean height)"
    );
    println!(
        "{:<16} {:>8} {:<14} {:>10} {:>10} {:>9} {:>10} {:>10} {:>8}",
        "material", "captures", "method", "mean deg", "p95 deg", "pred deg", "height/rng", "range mm", "fit s"
    );
    for r in &rows {
        let e = &r.errors;
        println!(
            "{:<16} {:>8} {:<14} {:>10.2} {:>10.2} {:>9.2} {:>10.4} {:>10.3} {:>8.3}",
            r.material,
            r.captures,
            r.method,
            e.normal_mean_deg,
            e.normal_p95_deg,
            e.predicted_sigma_deg,
            e.height_rel_rmse,
            e.height_range_m * 1e3,
            r.fit_s
        );
    }
    car::print_rows(&cars);
    if fits.is_empty() {
        return Ok(());
    }
    println!();
    println!("reflectance models against the measured textures and the noise-free truth (relative RMSE)");
    println!(
        "{:<16} {:<44} {:>10} {:>10} {:>10} {:>9} {:>9}",
        "material", "model", "bytes", "vs data", "vs truth", "fit s", "eval s"
    );
    for r in &fits {
        println!(
            "{:<16} {:<44} {:>10} {:>10.4} {:>10} {:>9.3} {:>9.3}",
            r.material,
            r.model,
            r.bytes,
            r.rel_rmse_data,
            r.rel_rmse_truth.map_or("-".into(), |v| format!("{v:.4}")),
            r.fit_s,
            r.eval_s
        );
    }
    Ok(())
}
