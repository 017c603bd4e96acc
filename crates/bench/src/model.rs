//! `btfrig bench model`: the surface truth of a simulated dataset, for the error figures of
//! photometric stereo and the reflectance fits (docs/material-models.md).
//!
//! A dataset made on the simulated rig names its rig config (`rig.config_toml`, the sample's
//! side) and its plan names its material (`[rig] material`, default corduroy). From them
//! [`SimSurface`] regenerates the material's height field exactly as the renderer did and
//! answers [`SurfaceTruthProbe`]: per texel the normalised mean normal and the mean height
//! over the texel's area (`SUBSAMPLES`² point samples). The estimators never see it.

use anyhow::Context;
use btfrig_model::truth::{Region, SurfaceTruth, SurfaceTruthProbe};
use btfrig_render::heightfield::HeightField;
use btfrig_render::material::{Material, MaterialSpec};
use btfrig_store::Manifest;
use rayon::prelude::*;

/// Point samples per texel axis of the truth.
pub const SUBSAMPLES: usize = 4;

/// The default material of a plan that names none (as the simulated backend's).
pub const DEFAULT_MATERIAL: &str = "corduroy";

/// A simulated sample's true surface.
pub struct SimSurface {
    /// The material's name.
    pub material: String,
    height: HeightField,
}

impl SimSurface {
    /// The surface of `spec` on a sample of side `sample_side_m`.
    pub fn new(spec: &MaterialSpec, sample_side_m: f64) -> anyhow::Result<Self> {
        let m = Material::generate(spec, sample_side_m)?;
        Ok(SimSurface { material: spec.name.clone(), height: m.height })
    }

    /// The surface behind a dataset of the simulated rig: its rig config's sample side and
    /// its plan's material (or `material`, a built-in name, when given).
    pub fn for_dataset(manifest: &Manifest, material: Option<&str>) -> anyhow::Result<Self> {
        let rig = btfrig_core::config::RigConfig::from_toml(&manifest.rig.config_toml, "manifest rig.config_toml")
            .context("the dataset's rig config (the truth needs the sample's side)")?;
        let name = match material {
            Some(m) => m.to_string(),
            None => plan_material(&manifest.plan.text).unwrap_or_else(|| DEFAULT_MATERIAL.to_string()),
        };
        anyhow::ensure!(
            !name.ends_with(".toml"),
            "the dataset's plan names the material file {name:?}; the truth knows built-in materials only (pass --material NAME)"
        );
        let spec = MaterialSpec::builtin(&name).with_context(|| format!("material {name:?} of the dataset's plan"))?;
        Self::new(&spec, rig.plate.sample_side_m)
    }
}

/// `[rig] material` of a plan's text, if any.
fn plan_material(text: &str) -> Option<String> {
    let v: toml::Value = toml::from_str(text).ok()?;
    v.get("rig")?.get("material")?.as_str().map(String::from)
}

impl SurfaceTruthProbe for SimSurface {
    fn surface(&self, region: Region, width: usize, height: usize) -> SurfaceTruth {
        let k = SUBSAMPLES;
        let (dx, dy) = ((region.x_max - region.x_min) / width as f64, (region.y_max - region.y_min) / height as f64);
        let texels: Vec<([f64; 3], f64)> = (0..width * height)
            .into_par_iter()
            .map(|t| {
                let (col, row) = (t % width, t / width);
                let mut n = [0.0f64; 3];
                let mut h = 0.0;
                for a in 0..k {
                    for b in 0..k {
                        let x = region.x_min + (col as f64 + (b as f64 + 0.5) / k as f64) * dx;
                        let y = region.y_max - (row as f64 + (a as f64 + 0.5) / k as f64) * dy;
                        let v = self.height.normal(x, y);
                        n[0] += v.x;
                        n[1] += v.y;
                        n[2] += v.z;
                        h += self.height.height(x, y);
                    }
                }
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                ([n[0] / len, n[1] / len, n[2] / len], h / (k * k) as f64)
            })
            .collect();
        SurfaceTruth {
            width,
            height,
            normal: texels.iter().map(|t| t.0).collect(),
            height_m: texels.iter().map(|t| t.1).collect(),
        }
    }
}

/// The noise-free textures of a gonio dataset's captures: the renderer's ground truth at the
/// nominal pose of each `(light, view)` (sample frame), over the dataset's region at its texel
/// size, as radiance factors (the scale `btfrig bench compress` uses), each texel the mean of
/// `SUBSAMPLES`² point samples over its area (as the run report's truth). `None` for a dataset whose rig is not a gonioreflectometer.
pub fn truth_textures(
    manifest: &Manifest,
    material: &str,
    pairs: &[(btfrig_core::Direction, btfrig_core::Direction)],
) -> anyhow::Result<Option<Vec<Vec<[f32; 3]>>>> {
    let cfg = btfrig_core::config::RigConfig::from_toml(&manifest.rig.config_toml, "manifest rig.config_toml")?;
    if cfg.rig.kind.is_dome() {
        return Ok(None);
    }
    let spec = MaterialSpec::builtin(material)?;
    let scene = btfrig_render::rig_scene::RigScene::new(&cfg, &spec)?;
    let scale = (scene.sensor().dn_per_electron(1.0) / scene.white_signal_dn(1.0, 1.0)) as f32;
    let r = dataset_region(manifest);
    let region = btfrig_render::ground_truth::Region { x_min: r.x_min, x_max: r.x_max, y_min: r.y_min, y_max: r.y_max };
    let (w, h) = (manifest.texture.width as usize, manifest.texture.height as usize);
    let mut out = Vec::with_capacity(pairs.len());
    for (l, v) in pairs {
        let joints =
            scene.gonio().ik(*l, *v).map_err(|e| anyhow::anyhow!("truth of light {l:?}, view {v:?}: {e:?}"))?;
        let k = SUBSAMPLES;
        let gt = scene.renderer().ground_truth(&scene.pose(&joints), w * k, h * k, Some(region)).box_average(k);
        out.push(gt.data.iter().map(|p| p.map(|c| c * scale)).collect());
    }
    Ok(Some(out))
}

/// The region a dataset's textures cover.
pub fn dataset_region(manifest: &Manifest) -> Region {
    let r = manifest.texture.region;
    Region {
        x_min: r.center_m[0] - 0.5 * r.size_m[0],
        x_max: r.center_m[0] + 0.5 * r.size_m[0],
        y_min: r.center_m[1] - 0.5 * r.size_m[1],
        y_max: r.center_m[1] + 0.5 * r.size_m[1],
    }
}
