//! `btfrig model scaled-lafortune`, `btfrig model ptm` and their rows in `btfrig bench model`:
//! the per-view models of seed 000 section 3.1 (docs/material-models.md).

use std::path::PathBuf;
use std::time::Instant;

use btfrig_model::lafortune::{BtfInput, ALBEDO_BOUNDS, LOBE_BOUNDS};
use btfrig_model::ps::{PsMethod, PsParams};
use btfrig_model::ptm::{fit as fit_ptm, PtmInput, PtmMap, PtmParams};
use btfrig_model::scaled_lafortune::{fit as fit_scaled, ScaledLafortuneMap, ScaledParams};
use clap::Args;

use super::{dataset_region, linear_rows, lobe_maps, score, stack, write_descriptor, FitRow, Observations, Sums};

/// `btfrig model ptm`.
#[derive(Debug, Args)]
pub struct PtmArgs {
    /// The dataset directory (every view needs at least 6 distinct light directions).
    pub dataset: PathBuf,
    /// Output directory (new or empty; nothing is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Ridge of the per-view least squares, relative to the normal matrix's mean eigenvalue.
    #[arg(long, default_value_t = 1e-6)]
    pub ridge: f64,
    /// Print the descriptor as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Relative RMSE of `texture(l, v)` against every capture.
fn rel_data(obs: &Observations, texture: impl Fn(&[f64; 3], &[f64; 3]) -> Vec<[f32; 3]>) -> f64 {
    let mut sums = Sums::default();
    for (i, (l, v)) in obs.lights.iter().zip(&obs.views).enumerate() {
        sums.add(&texture(l, v), &obs.images[i]);
    }
    sums.rel()
}

fn scaled_map(obs: &Observations, lobes: usize, normals: Option<&[[f64; 3]]>) -> anyhow::Result<ScaledLafortuneMap> {
    let (refs, w, h) = obs.input();
    let input = BtfInput { texels: w * h, lights: &obs.lights, views: &obs.views, images: &refs, normals };
    Ok(fit_scaled(&input, &ScaledParams::new(lobes))?)
}

fn ptm_map(obs: &Observations, ridge: f64) -> anyhow::Result<PtmMap> {
    let (refs, w, h) = obs.input();
    let input = PtmInput { texels: w * h, lights: &obs.lights, views: &obs.views, images: &refs };
    Ok(fit_ptm(&input, &PtmParams { ridge })?)
}

/// Writes the descriptor; prints it (`--json`) or `summary` and where the maps are.
fn finish(out: &std::path::Path, desc: &serde_json::Value, json: bool, summary: &str) -> anyhow::Result<()> {
    let text = write_descriptor(out, desc)?;
    if json {
        println!("{text}");
    } else {
        println!("{summary}");
        println!("  maps             {}", out.display());
    }
    Ok(())
}

/// `btfrig model scaled-lafortune`.
pub fn scaled_lafortune(a: &super::LobeFitArgs) -> anyhow::Result<()> {
    let obs = Observations::read(&a.dataset, super::ViewSelection::default())?;
    let (w, h) = (obs.source.layout().width, obs.source.layout().height);
    let normals = if a.no_normals { None } else { Some(obs.normals(&PsParams::new(PsMethod::Robust))?.0.normal) };
    let t = Instant::now();
    let map = scaled_map(&obs, a.lobes, normals.as_deref())?;
    let fit_s = t.elapsed().as_secs_f64();
    let rel = rel_data(&obs, |l, v| map.texture(l, v));
    let out = crate::captures_cmd::prepare_output(Some(a.out.clone()), "btfrig-scaled-lafortune")?;
    let mut files = lobe_maps(&out, w, h, &map.lafortune)?;
    let nv = map.view_dirs.len();
    btfrig_imageio::write_rgb_exr(&out.join("view_scale.exr"), w, h * nv, &stack(&map.scale, w * h, nv))?;
    files.insert("view_scale".into(), serde_json::json!({ "file": "view_scale.exr", "channels": ["R"], "meaning": "view scale T in [0, 1] (each texel's largest is 1); view direction j (see view_dirs) is rows j*height .. (j+1)*height, grey in R = G = B" }));
    let desc = serde_json::json!({
        "format": "btfrig-material-maps",
        "version": 1,
        "model": "scaled-lafortune",
        "formula": "I_c(l, v) = T(v) * l_z (rho_c + sum_k max(0, C_xy,k (l_x v_x + l_y v_y) + C_z,k l_z v_z)^n_k), l and v in the texel's frame (normal map) or the sample frame; T at the nearest stored view direction",
        "lobes": a.lobes,
        "relative_to_normals": normals.is_some(),
        "bounds": { "albedo": ALBEDO_BOUNDS, "lobe": LOBE_BOUNDS, "view_scale": [0.0, 1.0] },
        "view_dirs": map.view_dirs,
        "source": { "dataset": a.dataset.display().to_string(), "manifest_plan_hash": obs.source.manifest().plan.hash, "captures": obs.lights.len() },
        "width": w, "height": h,
        "region_m": dataset_region(obs.source.manifest()),
        "maps": files,
        "rel_rmse_data": rel,
        "fit_s": fit_s,
    });
    let summary = format!(
        "btfrig model scaled-lafortune: {} lobe(s), {nv} view scales, {w} x {h} texels, relative RMSE {rel:.4} against the {} captures, {fit_s:.2} s",
        a.lobes,
        obs.lights.len()
    );
    finish(&out, &desc, a.json, &summary)
}

/// `btfrig model ptm`.
pub fn ptm(a: &PtmArgs) -> anyhow::Result<()> {
    let obs = Observations::read(&a.dataset, super::ViewSelection::default())?;
    let (w, h) = (obs.source.layout().width, obs.source.layout().height);
    let t = Instant::now();
    let map = ptm_map(&obs, a.ridge)?;
    let fit_s = t.elapsed().as_secs_f64();
    let rel = rel_data(&obs, |l, v| map.texture(l, v));
    let out = crate::captures_cmd::prepare_output(Some(a.out.clone()), "btfrig-ptm")?;
    // View j's map occupies rows j*h .. (j+1)*h of each file.
    let quad: Vec<[f32; 3]> = map.coeffs.iter().map(|a| [a[0], a[1], a[2]]).collect();
    let lin: Vec<[f32; 3]> = map.coeffs.iter().map(|a| [a[3], a[4], a[5]]).collect();
    let chroma = &map.chroma;
    let nv = map.views.len();
    for (name, data) in [("ptm_quadratic.exr", &quad), ("ptm_linear.exr", &lin), ("ptm_chroma.exr", chroma)] {
        btfrig_imageio::write_rgb_exr(&out.join(name), w, h * nv, data)?;
    }
    let worst = map.views.iter().map(|v| v.rcond).fold(f64::INFINITY, f64::min);
    let desc = serde_json::json!({
        "format": "btfrig-material-maps",
        "version": 1,
        "model": "ptm",
        "formula": "L = a0 lu^2 + a1 lv^2 + a2 lu lv + a3 lu + a4 lv + a5 with (lu, lv) = (l_x, l_y) of the unit light direction in the sample frame; I_c = max(0, chroma_c * L); the map of the nearest stored view",
        "views": map.views,
        "ridge": a.ridge,
        "worst_rcond": worst,
        "source": { "dataset": a.dataset.display().to_string(), "manifest_plan_hash": obs.source.manifest().plan.hash, "captures": obs.lights.len() },
        "width": w, "height": h,
        "region_m": dataset_region(obs.source.manifest()),
        "maps": {
            "quadratic": { "file": "ptm_quadratic.exr", "channels": ["R", "G", "B"], "meaning": "R = a0 (lu^2), G = a1 (lv^2), B = a2 (lu lv); view j (see views) is rows j*height .. (j+1)*height" },
            "linear": { "file": "ptm_linear.exr", "channels": ["R", "G", "B"], "meaning": "R = a3 (lu), G = a4 (lv), B = a5 (constant); same stacking" },
            "chroma": { "file": "ptm_chroma.exr", "channels": ["R", "G", "B"], "meaning": "chroma_c multiplying the luminance polynomial per channel (mean 1 for grey); same stacking" },
        },
        "rel_rmse_data": rel,
        "fit_s": fit_s,
    });
    let summary = format!(
        "btfrig model ptm: {nv} views, {w} x {h} texels, relative RMSE {rel:.4} against the {} captures, worst reciprocal condition {worst:.1e}, {fit_s:.2} s",
        obs.lights.len()
    );
    finish(&out, &desc, a.json, &summary)
}

/// `bench model`'s rows of the per-view models: scaled Lafortune (1 and 2 lobes, relative to
/// `normals`) and the PTM, each followed by FMF and PCMF of at least its storage. A dataset
/// with too few lights per view for a PTM gets a note on stderr instead of its rows.
pub(super) fn rows(
    obs: &mut Observations,
    material: &str,
    truth: Option<&Vec<Vec<[f32; 3]>>>,
    normals: &[[f64; 3]],
    rows: &mut Vec<FitRow>,
) -> anyhow::Result<()> {
    let texels = obs.source.layout().texels();
    for k in [1, 2] {
        let t = Instant::now();
        let map = scaled_map(obs, k, Some(normals))?;
        let fit_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let decoded: Vec<Vec<[f32; 3]>> = obs.lights.iter().zip(&obs.views).map(|(l, v)| map.texture(l, v)).collect();
        let eval_s = t.elapsed().as_secs_f64();
        let (e_data, e_truth) = score(&decoded, obs, truth);
        // Half floats for albedo, lobes and normal (2); one byte per view scale in [0, 1].
        let bytes = texels * ((map.lafortune.values_per_texel() + 2) * 2 + map.view_dirs.len());
        let label = format!("scaled-lafortune-{k}+normal");
        rows.push(FitRow {
            material: material.into(),
            model: format!("{label} ({} views)", map.view_dirs.len()),
            bytes,
            rel_rmse_data: e_data,
            rel_rmse_truth: e_truth,
            fit_s,
            eval_s,
        });
        linear_rows(obs, material, bytes, &label, truth, rows)?;
    }
    let t = Instant::now();
    let map = match ptm_map(obs, PtmParams::default().ridge) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("bench model: {material}: no PTM rows: {e}");
            return Ok(());
        }
    };
    let fit_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let decoded: Vec<Vec<[f32; 3]>> = obs.lights.iter().zip(&obs.views).map(|(l, v)| map.texture(l, v)).collect();
    let eval_s = t.elapsed().as_secs_f64();
    let (e_data, e_truth) = score(&decoded, obs, truth);
    // Half floats: 6 coefficients and 3 chroma per texel and view.
    let bytes = texels * map.values_per_texel() * 2;
    let worst = map.views.iter().map(|v| v.rcond).fold(f64::INFINITY, f64::min);
    rows.push(FitRow {
        material: material.into(),
        model: format!("ptm ({} views, rcond {worst:.0e})", map.views.len()),
        bytes,
        rel_rmse_data: e_data,
        rel_rmse_truth: e_truth,
        fit_s,
        eval_s,
    });
    linear_rows(obs, material, bytes, "ptm", truth, rows)
}
