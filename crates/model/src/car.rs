//! Probabilistic BTF model by causal autoregressive (CAR) texture synthesis (seed 002).
//!
//! Analysis ([`fit`]):
//! 1. **Segmentation** ([`segment`]): the dataset's (light, view) pairs are clustered into
//!    sub-spaces by seeded k-means on their textures' colour distributions (not on
//!    directions: the seed clusters by appearance, so pairs that look alike share a model
//!    wherever they lie on the hemisphere). Each sub-space is represented by its member
//!    texture nearest the cluster's mean features.
//! 2. **Bump mapping, analysis side** ([`bump`]): with a range (height) map, the
//!    representative texture is divided by its shading factor under its own light, so the
//!    CAR models the smooth part only.
//! 3. **Spectral factorisation** ([`colour`]): PCA over the three channels, three
//!    uncorrelated mono-spectral factors.
//! 4. **Spatial factorisation** ([`pyramid`]): a Gaussian-Laplacian pyramid per factor.
//! 5. **CAR per factor and level** ([`ar`]): least-squares / Bayesian estimate, noise variance,
//!    spectral radius.
//!
//! The range map itself is kept for the synthesis either as a multi-scale CAR model of the
//! heights (the default: any size without seams or repetition, the relief statistically
//! alike) or as the measured map enlarged by mirrored tiling (the relief exact, repeating
//! with twice the map's period) — [`RangeEnlargement`].
//!
//! Synthesis ([`CarBtf::synthesise`]) of any size for any (light, view) pair: the pair's
//! sub-space (that of the nearest measured pair, by the sum of the light and view directions'
//! Euclidean distances), each factor's levels by the causal recursion driven by seeded white
//! noise, the pyramid collapsed, the colour decorrelation inverted; then multiplied by the
//! shading factor of the enlarged range map's normals under the pair's light.

pub mod ar;
pub mod bump;
pub mod colour;
pub mod pyramid;
pub mod segment;
pub mod stats;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use ar::CarModel;
use colour::ColourPca;
use pyramid::Level;

/// How the range map is enlarged to the synthesised size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RangeEnlargement {
    /// A multi-scale CAR model of the heights, synthesised like a colour factor.
    Car,
    /// The measured heights, tiled with mirrored repetition.
    Mirror,
}

/// Knobs of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CarParams {
    /// Sub-spaces (k of the k-means; fewer when there are fewer distinct pairs).
    pub clusters: usize,
    /// Pyramid levels (fewer when the texture is too small for the neighbourhood).
    pub levels: usize,
    /// Radius of the causal neighbourhood ([`ar::neighbourhood`]).
    pub radius: usize,
    /// Seed of the k-means.
    pub seed: u64,
    /// Enlargement of the range map.
    pub range: RangeEnlargement,
}

impl Default for CarParams {
    fn default() -> Self {
        CarParams { clusters: 4, levels: 3, radius: 2, seed: 2, range: RangeEnlargement::Car }
    }
}

/// The measured BTF: textures on one texel grid and each one's directions.
#[derive(Debug, Clone, Copy)]
pub struct CarInput<'a> {
    /// Which data (in messages).
    pub what: &'a str,
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Light direction of each texture (sample frame, unit).
    pub lights: &'a [[f64; 3]],
    /// View direction of each texture.
    pub views: &'a [[f64; 3]],
    /// The textures, linear RGB, row-major.
    pub images: &'a [&'a [[f32; 3]]],
    /// The range map (metres, row-major, the same grid), or none: no bump mapping.
    pub heights: Option<&'a [f64]>,
    /// Texel side in metres (the range map's slopes).
    pub texel_m: f64,
}

/// One band's multi-scale model: a CAR model per pyramid level (finest first), and the band's
/// mean and standard deviation.
///
/// The levels are synthesised independently, so the covariance between a Laplacian level and
/// the expansion of the next (not zero: the pyramid is not orthogonal) is lost and the
/// collapsed band comes out with too little variance (0.68 of it with 3 levels on the
/// stationary test texture). The synthesis therefore matches the collapsed band's mean and
/// standard deviation to the measured band's (moment matching, 2 values).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BandModel {
    /// The levels' models.
    pub levels: Vec<CarModel>,
    /// The measured band's mean.
    pub mean: f64,
    /// The measured band's standard deviation.
    pub std: f64,
}

impl BandModel {
    /// Fits the levels of a `width x height` band; bands (levels) with a standard deviation at
    /// most `floor_std` are constant.
    pub fn fit(
        what: &str,
        width: usize,
        height: usize,
        band: &[f64],
        levels: usize,
        radius: usize,
        floor_std: f64,
    ) -> Result<Self> {
        let pyr = pyramid::decompose(Level { width, height, data: band.to_vec() }, levels);
        let levels = pyr
            .iter()
            .enumerate()
            .map(|(k, l)| ar::fit(&format!("{what}, level {k}"), l.width, l.height, &l.data, radius, floor_std))
            .collect::<Result<Vec<_>>>()?;
        let (mean, std) = mean_std(band);
        Ok(BandModel { levels, mean, std })
    }

    /// Synthesises a `width x height` band.
    pub fn synthesise(&self, what: &str, width: usize, height: usize, rng: &mut ChaCha8Rng) -> Result<Vec<f64>> {
        let sizes = pyramid::sizes(width, height, self.levels.len());
        let mut pyr = Vec::with_capacity(sizes.len());
        for (k, (m, &(w, h))) in self.levels.iter().zip(&sizes).enumerate() {
            pyr.push(Level { width: w, height: h, data: ar::synthesise(&format!("{what}, level {k}"), m, w, h, rng)? });
        }
        let mut band = pyramid::collapse(&pyr).data;
        let (m, s) = mean_std(&band);
        let gain = if s > 0.0 { self.std / s } else { 0.0 };
        for v in &mut band {
            *v = self.mean + gain * (*v - m);
        }
        Ok(band)
    }

    /// Values stored.
    pub fn values(&self) -> usize {
        self.levels.iter().map(CarModel::values).sum::<usize>() + 2
    }
}

/// One sub-space's model: colour decorrelation and a multi-scale CAR per factor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubspaceModel {
    /// The measured pair (index into [`CarBtf::pairs`]) whose texture was modelled.
    pub representative: usize,
    /// Spectral decorrelation.
    pub colour: ColourPca,
    /// The three factors' models.
    pub factors: Vec<BandModel>,
}

impl SubspaceModel {
    /// Values stored: the 3x3 basis, the mean colour and the factors' models.
    pub fn values(&self) -> usize {
        12 + self.factors.iter().map(BandModel::values).sum::<usize>()
    }
}

/// A measured (light, view) pair and its sub-space.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pair {
    /// Light direction.
    pub light: [f64; 3],
    /// View direction.
    pub view: [f64; 3],
    /// Sub-space index.
    pub subspace: usize,
}

/// The range map kept for the synthesis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RangeMap {
    /// How it is enlarged.
    pub enlargement: RangeEnlargement,
    /// Texel side, metres.
    pub texel_m: f64,
    /// The multi-scale CAR model of the heights ([`RangeEnlargement::Car`]).
    pub model: Option<BandModel>,
    /// RMS height difference between neighbouring texels (along rows and columns), metres: a
    /// synthesised range map is scaled to it, since the bump filter sees slopes, not heights.
    pub slope_rms: f64,
    /// The measured heights, metres ([`RangeEnlargement::Mirror`]; empty otherwise).
    pub heights: Vec<f32>,
}

/// The fitted probabilistic BTF model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CarBtf {
    /// Measured texture width (the range map's).
    pub width: usize,
    /// Measured texture height.
    pub height: usize,
    /// Parameters of the fit.
    pub params: CarParams,
    /// The measured pairs and their sub-spaces (the seed's sub-space index table).
    pub pairs: Vec<Pair>,
    /// Sub-space models.
    pub subspaces: Vec<SubspaceModel>,
    /// The range map, if bump mapping is used.
    pub range: Option<RangeMap>,
}

/// A synthesised texture and where it came from.
#[derive(Debug, Clone)]
pub struct Synthesis {
    /// Linear RGB, row-major.
    pub texture: Vec<[f32; 3]>,
    /// The nearest measured pair.
    pub nearest_pair: usize,
    /// Its sub-space.
    pub subspace: usize,
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt())
}

/// RMS difference between horizontally and vertically neighbouring values.
fn neighbour_rms(width: usize, height: usize, v: &[f64]) -> f64 {
    let dx = (0..height).flat_map(|y| (1..width).map(move |x| v[y * width + x] - v[y * width + x - 1]));
    let dy = (1..height).flat_map(|y| (0..width).map(move |x| v[y * width + x] - v[(y - 1) * width + x]));
    rms(dx.chain(dy))
}

fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    (s / n.max(1) as f64).sqrt()
}

/// Relative floor below which a band is constant: far above rounding, far below any texture.
const CONSTANT_BAND: f64 = 1e-7;

/// Levels that fit: every level at least `2r + 2` wide and `r + 2` high with enough samples.
fn feasible_levels(width: usize, height: usize, levels: usize, radius: usize) -> usize {
    let eta = radius * (2 * radius + 2);
    let ok = |w: usize, h: usize| {
        w > 2 * radius && h > radius && w.saturating_sub(2 * radius) * h.saturating_sub(radius) > eta
    };
    pyramid::sizes(width, height, levels.max(1)).iter().take_while(|&&(w, h)| ok(w, h)).count().max(1)
}

fn check(input: &CarInput, p: &CarParams) -> Result<()> {
    let n = input.images.len();
    if n == 0 {
        return Err(ModelError::Empty(format!("{}: no textures to model", input.what)));
    }
    for (name, len) in [("light directions", input.lights.len()), ("view directions", input.views.len())] {
        if len != n {
            return Err(ModelError::WrongSize { what: format!("{}: {name}", input.what), got: len, expected: n });
        }
    }
    let texels = input.width * input.height;
    if let Some((i, img)) = input.images.iter().enumerate().find(|(_, img)| img.len() != texels) {
        return Err(ModelError::WrongSize {
            what: format!("{}: texture {i}", input.what),
            got: img.len(),
            expected: texels,
        });
    }
    if let Some(h) = input.heights {
        if h.len() != texels {
            return Err(ModelError::WrongSize {
                what: format!("{}: range map", input.what),
                got: h.len(),
                expected: texels,
            });
        }
        if !(input.texel_m.is_finite() && input.texel_m > 0.0) {
            return Err(ModelError::OutOfRange {
                field: format!("{}: texel size", input.what),
                value: format!("{}", input.texel_m),
                allowed: "a positive length in metres".into(),
            });
        }
    }
    for (field, v, allowed) in [
        ("clusters", p.clusters, "at least 1"),
        ("levels", p.levels, "at least 1"),
        ("radius", p.radius, "1 or more (1: 4 neighbours, 2: 12)"),
    ] {
        if v == 0 {
            return Err(ModelError::OutOfRange { field: field.into(), value: "0".into(), allowed: allowed.into() });
        }
    }
    Ok(())
}

/// Fits the model to a measured BTF (module documentation).
pub fn fit(input: &CarInput, p: &CarParams) -> Result<CarBtf> {
    check(input, p)?;
    let (w, h) = (input.width, input.height);
    let levels = feasible_levels(w, h, p.levels, p.radius);
    let feats: Vec<Vec<f64>> = input.images.iter().map(|img| segment::features(img)).collect();
    let assign = segment::kmeans(&feats, p.clusters, p.seed);
    let clusters = assign.iter().max().map_or(0, |m| m + 1);
    let normals = input.heights.map(|hm| bump::normals(w, h, hm, input.texel_m));
    let mut subspaces = Vec::with_capacity(clusters);
    for c in 0..clusters {
        let members: Vec<usize> = (0..assign.len()).filter(|&i| assign[i] == c).collect();
        let dim = feats[0].len();
        let centre: Vec<f64> =
            (0..dim).map(|d| members.iter().map(|&i| feats[i][d]).sum::<f64>() / members.len() as f64).collect();
        let d2 = |i: usize| feats[i].iter().zip(&centre).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        let rep =
            members.iter().copied().min_by(|&a, &b| d2(a).total_cmp(&d2(b))).expect("k-means clusters are not empty");
        let what = format!("{}: sub-space {c} (pair {rep})", input.what);
        let smooth: Vec<[f32; 3]> = match &normals {
            Some(n) => {
                let s = bump::shading(n, &input.lights[rep]);
                input.images[rep]
                    .iter()
                    .zip(&s)
                    .map(|(px, s)| px.map(|v| (f64::from(v) / s.max(bump::MIN_SHADE)) as f32))
                    .collect()
            }
            None => input.images[rep].to_vec(),
        };
        let colour = ColourPca::fit(&what, &smooth)?;
        let floor = CONSTANT_BAND * rms(smooth.iter().flat_map(|px| px.map(f64::from)));
        let factor_bands: Vec<Vec<f64>> =
            (0..3).map(|k| smooth.iter().map(|px| colour.forward(*px)[k]).collect()).collect();
        let factors = factor_bands
            .iter()
            .enumerate()
            .map(|(k, band)| BandModel::fit(&format!("{what}, factor {k}"), w, h, band, levels, p.radius, floor))
            .collect::<Result<Vec<_>>>()?;
        subspaces.push(SubspaceModel { representative: rep, colour, factors });
    }
    let range = match input.heights {
        None => None,
        Some(hm) => {
            let (model, heights) = match p.range {
                RangeEnlargement::Car => {
                    let floor = CONSTANT_BAND * rms(hm.iter().copied());
                    let what = format!("{}: range map", input.what);
                    (Some(BandModel::fit(&what, w, h, hm, levels, p.radius, floor)?), Vec::new())
                }
                RangeEnlargement::Mirror => (None, hm.iter().map(|v| *v as f32).collect()),
            };
            let slope_rms = neighbour_rms(w, h, hm);
            Some(RangeMap { enlargement: p.range, texel_m: input.texel_m, model, slope_rms, heights })
        }
    };
    let pairs =
        (0..assign.len()).map(|i| Pair { light: input.lights[i], view: input.views[i], subspace: assign[i] }).collect();
    Ok(CarBtf { width: w, height: h, params: *p, pairs, subspaces, range })
}

impl CarBtf {
    /// The measured pair nearest to `(l, v)` (sum of the directions' squared distances).
    pub fn nearest_pair(&self, l: &[f64; 3], v: &[f64; 3]) -> usize {
        let d = |p: &Pair| dist2(&p.light, l) + dist2(&p.view, v);
        (0..self.pairs.len()).min_by(|&a, &b| d(&self.pairs[a]).total_cmp(&d(&self.pairs[b]))).unwrap_or(0)
    }

    /// Bytes of the model's parameters as 4-byte floats, plus one byte per pair for the
    /// sub-space index table (the pairs' directions are the plan's, not counted).
    pub fn parameter_bytes(&self) -> usize {
        4 * self.subspaces.iter().map(SubspaceModel::values).sum::<usize>() + self.pairs.len()
    }

    /// Bytes of the range map: its CAR model (4-byte floats) or the heights (half floats).
    pub fn range_bytes(&self) -> usize {
        self.range.as_ref().map_or(0, |r| match &r.model {
            Some(m) => 4 * m.values() + 8,
            None => 2 * r.heights.len() + 8,
        })
    }

    /// The enlarged range map at `width x height` (the same for every pair of one seed).
    pub fn heights(&self, width: usize, height: usize, seed: u64) -> Result<Option<Vec<f64>>> {
        let Some(r) = &self.range else { return Ok(None) };
        Ok(Some(match &r.model {
            Some(m) => {
                // A stream of its own: the relief does not change with the pair.
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(1);
                let mut hm = m.synthesise("range map", width, height, &mut rng)?;
                // The CAR keeps the heights' variance; the shading needs their slopes, which a
                // smooth (near unit-root) range map's model reproduces less well: match them.
                let s = neighbour_rms(width, height, &hm);
                let gain = if s > 0.0 { r.slope_rms / s } else { 0.0 };
                for v in &mut hm {
                    *v = m.mean + gain * (*v - m.mean);
                }
                hm
            }
            None => {
                let hm: Vec<f64> = r.heights.iter().map(|v| f64::from(*v)).collect();
                bump::tile_mirrored(self.width, self.height, &hm, width, height)
            }
        }))
    }

    /// Synthesises a `width x height` texture for the pair `(l, v)` from the noise of `seed`.
    pub fn synthesise(&self, l: &[f64; 3], v: &[f64; 3], width: usize, height: usize, seed: u64) -> Result<Synthesis> {
        if width == 0 || height == 0 {
            return Err(ModelError::OutOfRange {
                field: "synthesised size".into(),
                value: format!("{width}x{height}"),
                allowed: "at least 1x1".into(),
            });
        }
        if !(l.iter().chain(v).all(|x| x.is_finite()) && l[2] > 0.0 && v[2] > 0.0) {
            return Err(ModelError::OutOfRange {
                field: "light, view".into(),
                value: format!("{l:?}, {v:?}"),
                allowed: "finite directions above the sample's horizon (z > 0)".into(),
            });
        }
        let nearest = self.nearest_pair(l, v);
        let c = self.pairs[nearest].subspace;
        let sub = &self.subspaces[c];
        // Each factor has a noise stream of its own, so they run in parallel and a sub-space's
        // texture is the same for every pair of it.
        let (factors, heights) = rayon::join(
            || {
                sub.factors
                    .par_iter()
                    .enumerate()
                    .map(|(k, f)| {
                        let mut rng = ChaCha8Rng::seed_from_u64(seed);
                        rng.set_stream(2 + 3 * c as u64 + k as u64);
                        f.synthesise(&format!("sub-space {c}, factor {k}"), width, height, &mut rng)
                    })
                    .collect::<Result<Vec<_>>>()
            },
            || self.heights(width, height, seed),
        );
        let factors = factors?;
        let mut texture: Vec<[f32; 3]> =
            (0..width * height).map(|i| sub.colour.inverse([factors[0][i], factors[1][i], factors[2][i]])).collect();
        if let (Some(hm), Some(r)) = (heights?, &self.range) {
            let s = bump::shading(&bump::normals(width, height, &hm, r.texel_m), l);
            for (px, s) in texture.iter_mut().zip(&s) {
                *px = px.map(|x| (f64::from(x) * s) as f32);
            }
        }
        Ok(Synthesis { texture, nearest_pair: nearest, subspace: c })
    }
}
