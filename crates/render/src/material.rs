//! Materials: procedurally generated height fields with spatially varying reflectance.
//!
//! A material file (`sim/materials/*.toml`, format in `docs/materials.md`) names `K` basis
//! reflectance spectra and describes, with seeded procedural [`Pattern`]s, the height field
//! (a sum of layers), the per-texel mix of the basis spectra, and an optional GGX glossy lobe
//! whose strength may vary over the sample. [`Material::generate`] evaluates it on a texel
//! grid spanning the sample region. Colours stay symbolic here (spectrum names); the
//! [`crate::scene::Scene`] resolves them.

use serde::{Deserialize, Serialize};

use crate::heightfield::HeightField;

/// Built-in materials (the files of `sim/materials/`, embedded).
pub const BUILTIN_MATERIALS: &[(&str, &str)] = &[
    ("lacquered-wood", include_str!("../../../sim/materials/lacquered-wood.toml")),
    ("corduroy", include_str!("../../../sim/materials/corduroy.toml")),
    ("glazed-tile", include_str!("../../../sim/materials/glazed-tile.toml")),
    ("leather", include_str!("../../../sim/materials/leather.toml")),
];

/// A problem with a material description.
#[derive(Debug, thiserror::Error)]
pub enum MaterialError {
    /// Not valid TOML or not the schema (the message names the field).
    #[error("{origin}: {message}")]
    Parse {
        /// Where the text came from.
        origin: String,
        /// Parser message.
        message: String,
    },
    /// A value out of its allowed range.
    #[error("material {material}: {field} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Material name.
        material: String,
        /// Field path, e.g. `albedo.stops[1]`.
        field: String,
        /// The value as written.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// No built-in material of that name.
    #[error("unknown material {0:?}: built-in are lacquered-wood, corduroy, glazed-tile, leather")]
    Unknown(String),
}

/// A material file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Name, e.g. `corduroy`.
    pub name: String,
    /// One line for people.
    #[serde(default)]
    pub description: String,
    /// Texels per side of the square texture over the sample region (`8..=4096`).
    pub texels: usize,
    /// Seed of every procedural pattern.
    pub seed: u64,
    /// Basis reflectance spectra (names for the colour system), `1..=16` of them.
    pub basis: Vec<String>,
    /// Height layers, summed; none means a flat sample.
    #[serde(default)]
    pub height: Vec<HeightLayer>,
    /// The diffuse albedo: a pattern mapped to basis weights.
    pub albedo: AlbedoSpec,
    /// The glossy lobe, if any.
    #[serde(default)]
    pub specular: Option<SpecularSpec>,
}

/// One height layer: `amplitude_m * pattern(x, y)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeightLayer {
    /// Height of the pattern's value 1, metres (`-0.01..=0.01`).
    pub amplitude_m: f64,
    /// The pattern (values in `[0, 1]`).
    pub pattern: Pattern,
}

/// Diffuse albedo: a pattern value `v` in `[0, 1]` picks basis weights by linear
/// interpolation between evenly spaced `stops` (`stops[0]` at `v = 0`, the last at `v = 1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlbedoSpec {
    /// The pattern.
    pub pattern: Pattern,
    /// Weight vectors, one weight per basis spectrum, each weight `>= 0`, each sum `<= 1`.
    pub stops: Vec<Vec<f64>>,
}

/// The glossy GGX lobe. The diffuse part of a texel is scaled by `1 - strength` so that
/// diffuse plus glossy never reflects more than comes in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpecularSpec {
    /// Strength (constant Fresnel factor) in `[0, 1]`.
    pub strength: f64,
    /// GGX roughness `alpha` in `[0.01, 1]`.
    pub roughness: f64,
    /// Spectrum of the lobe (a dielectric reflects the lamp's colour: `flat:1`).
    #[serde(default = "SpecularSpec::default_colour")]
    pub colour: String,
    /// Optional variation: `strength(x) = low + (strength - low) * pattern(x)`.
    #[serde(default)]
    pub vary: Option<Vary>,
}

impl SpecularSpec {
    fn default_colour() -> String {
        "flat:1".into()
    }
}

/// Spatial variation of the glossy strength.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Vary {
    /// The pattern.
    pub pattern: Pattern,
    /// Strength where the pattern is 0, in `[0, 1]`.
    pub low: f64,
}

/// Profile of a ridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RidgeProfile {
    /// `0.5 + 0.5 cos`: smooth waves.
    Sine,
    /// Half-ellipse ridges over `duty` of the period with flat grooves between (corduroy wales).
    Round,
}

/// A procedural scalar field with values in `[0, 1]`, positions in metres on the sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Pattern {
    /// The same value everywhere.
    Constant {
        /// Value in `[0, 1]`.
        value: f64,
    },
    /// Fractal value noise (fBm).
    Noise {
        /// Feature size of the first octave, metres.
        scale_m: f64,
        /// Octaves (`1..=8`), each half the size of the previous.
        #[serde(default = "default_octaves")]
        octaves: u32,
        /// Amplitude ratio of successive octaves (`0..=1`).
        #[serde(default = "default_gain")]
        gain: f64,
        /// Mixed into the seed so two noise patterns of one material differ.
        #[serde(default)]
        salt: u64,
    },
    /// Parallel ridges running along `angle_deg` (from the x axis towards y).
    Ridges {
        /// Ridge pitch, metres.
        period_m: f64,
        /// Direction the ridges run in, degrees.
        #[serde(default)]
        angle_deg: f64,
        /// Profile of one ridge.
        profile: RidgeProfile,
        /// Fraction of the period covered by the ridge (`Round` only), `(0, 1]`.
        #[serde(default = "default_duty")]
        duty: f64,
    },
    /// Growth rings of wood: bands along `angle_deg`, warped by noise.
    Wood {
        /// Ring spacing, metres.
        ring_m: f64,
        /// Direction of the grain, degrees.
        #[serde(default)]
        angle_deg: f64,
        /// Warp amplitude, metres.
        warp_m: f64,
        /// Feature size of the warp noise, metres.
        warp_scale_m: f64,
        /// Exponent that thins the dark late-wood bands (`>= 0.1`).
        #[serde(default = "default_sharpness")]
        sharpness: f64,
    },
    /// Square tiles (1) separated by grout lines (0), with a bevel ramp between.
    Tiles {
        /// Tile pitch, metres.
        tile_m: f64,
        /// Grout line width, metres.
        grout_m: f64,
        /// Width of the ramp from grout to tile top, metres.
        bevel_m: f64,
    },
    /// Leather-like pebbles: cellular (Worley) noise, 0 in the creases between cells.
    Cells {
        /// Mean cell size, metres.
        cell_m: f64,
        /// Width over which a crease rises to the pebble top, metres.
        crease_m: f64,
        /// Mixed into the seed.
        #[serde(default)]
        salt: u64,
    },
}

const fn default_octaves() -> u32 {
    4
}
const fn default_gain() -> f64 {
    0.5
}
const fn default_duty() -> f64 {
    1.0
}
const fn default_sharpness() -> f64 {
    1.0
}

fn hash(mut x: u64) -> u64 {
    // splitmix64 finaliser: a good, fast 64-bit mix; deterministic across platforms.
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn lattice(seed: u64, ix: i64, iy: i64) -> f64 {
    let h = hash(seed ^ hash((ix as u64).wrapping_mul(0x1000_0000_01B3) ^ hash(iy as u64)));
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn smooth(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let (sx, sy) = (smooth(x - fx), smooth(y - fy));
    let a = lattice(seed, ix, iy);
    let b = lattice(seed, ix + 1, iy);
    let c = lattice(seed, ix, iy + 1);
    let d = lattice(seed, ix + 1, iy + 1);
    let top = a + (b - a) * sx;
    let bot = c + (d - c) * sx;
    top + (bot - top) * sy
}

fn fbm(seed: u64, x: f64, y: f64, scale: f64, octaves: u32, gain: f64) -> f64 {
    let (mut sum, mut norm, mut amp, mut f) = (0.0, 0.0, 1.0, 1.0 / scale);
    for o in 0..octaves {
        sum += amp * value_noise(seed.wrapping_add(o as u64 * 7919), x * f, y * f);
        norm += amp;
        amp *= gain;
        f *= 2.0;
    }
    if norm > 0.0 {
        sum / norm
    } else {
        0.5
    }
}

impl Pattern {
    /// The pattern's value at `(x, y)` metres (sample frame), in `[0, 1]`. Every pattern of a
    /// material gets the material's seed, so equal patterns coincide (a crease in the height
    /// is a crease in the albedo); `salt` makes two noise patterns differ.
    pub fn eval(&self, seed: u64, x: f64, y: f64) -> f64 {
        let v = match *self {
            Pattern::Constant { value } => value,
            Pattern::Noise { scale_m, octaves, gain, salt } => {
                fbm(hash(seed ^ hash(salt)), x, y, scale_m, octaves, gain)
            }
            Pattern::Ridges { period_m, angle_deg, profile, duty } => {
                let (s, c) = angle_deg.to_radians().sin_cos();
                let w = (-x * s + y * c) / period_m;
                let f = w - w.floor();
                match profile {
                    RidgeProfile::Sine => 0.5 + 0.5 * (std::f64::consts::TAU * f).cos(),
                    RidgeProfile::Round => {
                        if f < duty {
                            let u = 2.0 * f / duty - 1.0;
                            (1.0 - u * u).max(0.0).sqrt()
                        } else {
                            0.0
                        }
                    }
                }
            }
            Pattern::Wood { ring_m, angle_deg, warp_m, warp_scale_m, sharpness } => {
                let (s, c) = angle_deg.to_radians().sin_cos();
                let along = x * c + y * s;
                let across = -x * s + y * c;
                // Stretch the warp noise along the grain: fibres are long.
                let n = fbm(hash(seed ^ 0x5757), along / 6.0, across, warp_scale_m, 4, 0.5);
                let w = (across + warp_m * (n - 0.5) * 2.0) / ring_m;
                (0.5 + 0.5 * (std::f64::consts::TAU * w).cos()).powf(sharpness)
            }
            Pattern::Tiles { tile_m, grout_m, bevel_m } => {
                let lx = x.rem_euclid(tile_m);
                let ly = y.rem_euclid(tile_m);
                let d = lx.min(tile_m - lx).min(ly).min(tile_m - ly);
                let r = (d - grout_m / 2.0) / bevel_m.max(1e-12);
                smooth(r.clamp(0.0, 1.0))
            }
            Pattern::Cells { cell_m, crease_m, salt } => {
                let s = hash(seed ^ hash(salt.wrapping_add(0xCE11)));
                let (gx, gy) = (x / cell_m, y / cell_m);
                let (ix, iy) = (gx.floor() as i64, gy.floor() as i64);
                let (mut f1, mut f2) = (f64::INFINITY, f64::INFINITY);
                for j in iy - 1..=iy + 1 {
                    for i in ix - 1..=ix + 1 {
                        let px = i as f64 + lattice(s, i, j);
                        let py = j as f64 + lattice(s ^ 0xABCD, i, j);
                        let d = ((px - gx).powi(2) + (py - gy).powi(2)).sqrt();
                        if d < f1 {
                            f2 = f1;
                            f1 = d;
                        } else if d < f2 {
                            f2 = d;
                        }
                    }
                }
                // Distance to the cell border is about (F2 - F1)/2 cells; a rounded pebble profile.
                let r = ((f2 - f1) * 0.5 * cell_m / crease_m.max(1e-12)).clamp(0.0, 1.0);
                (1.0 - (1.0 - r).powi(2)).sqrt()
            }
        };
        v.clamp(0.0, 1.0)
    }

    fn validate(&self, material: &str, field: &str, errors: &mut Vec<MaterialError>) {
        let mut bad = |name: &str, v: f64, allowed: &str| {
            errors.push(MaterialError::OutOfRange {
                material: material.into(),
                field: format!("{field}.{name}"),
                value: v.to_string(),
                allowed: allowed.into(),
            })
        };
        let len = |v: f64| v.is_finite() && v > 0.0 && v <= 1.0;
        match *self {
            Pattern::Constant { value } => {
                if !(0.0..=1.0).contains(&value) {
                    bad("value", value, "[0, 1]")
                }
            }
            Pattern::Noise { scale_m, octaves, gain, .. } => {
                if !len(scale_m) {
                    bad("scale_m", scale_m, "(0, 1] metres")
                }
                if !(1..=8).contains(&octaves) {
                    bad("octaves", octaves as f64, "1..=8")
                }
                if !(0.0..=1.0).contains(&gain) {
                    bad("gain", gain, "[0, 1]")
                }
            }
            Pattern::Ridges { period_m, angle_deg, duty, .. } => {
                if !len(period_m) {
                    bad("period_m", period_m, "(0, 1] metres")
                }
                if !angle_deg.is_finite() {
                    bad("angle_deg", angle_deg, "a finite angle")
                }
                if !(duty > 0.0 && duty <= 1.0) {
                    bad("duty", duty, "(0, 1]")
                }
            }
            Pattern::Wood { ring_m, angle_deg, warp_m, warp_scale_m, sharpness } => {
                if !len(ring_m) {
                    bad("ring_m", ring_m, "(0, 1] metres")
                }
                if !angle_deg.is_finite() {
                    bad("angle_deg", angle_deg, "a finite angle")
                }
                if !(warp_m.is_finite() && (0.0..=1.0).contains(&warp_m)) {
                    bad("warp_m", warp_m, "[0, 1] metres")
                }
                if !len(warp_scale_m) {
                    bad("warp_scale_m", warp_scale_m, "(0, 1] metres")
                }
                if !(0.1..=20.0).contains(&sharpness) {
                    bad("sharpness", sharpness, "[0.1, 20]")
                }
            }
            Pattern::Tiles { tile_m, grout_m, bevel_m } => {
                if !len(tile_m) {
                    bad("tile_m", tile_m, "(0, 1] metres")
                }
                if !(grout_m >= 0.0 && grout_m + 2.0 * bevel_m < tile_m) {
                    bad("grout_m", grout_m, "[0, tile_m - 2 bevel_m) metres")
                }
                if !(bevel_m > 0.0 && bevel_m.is_finite()) {
                    bad("bevel_m", bevel_m, "> 0 metres")
                }
            }
            Pattern::Cells { cell_m, crease_m, .. } => {
                if !len(cell_m) {
                    bad("cell_m", cell_m, "(0, 1] metres")
                }
                if !(crease_m > 0.0 && crease_m <= cell_m) {
                    bad("crease_m", crease_m, "(0, cell_m] metres")
                }
            }
        }
    }
}

impl MaterialSpec {
    /// Parses a material file; `origin` names it in errors. The result is validated.
    pub fn from_toml(text: &str, origin: &str) -> Result<MaterialSpec, MaterialError> {
        let spec: MaterialSpec =
            toml::from_str(text).map_err(|e| MaterialError::Parse { origin: origin.into(), message: e.to_string() })?;
        let errors = spec.validate();
        match errors.into_iter().next() {
            None => Ok(spec),
            Some(e) => Err(e),
        }
    }

    /// A built-in material by name (see [`BUILTIN_MATERIALS`]).
    pub fn builtin(name: &str) -> Result<MaterialSpec, MaterialError> {
        let (_, text) =
            BUILTIN_MATERIALS.iter().find(|(n, _)| *n == name).ok_or_else(|| MaterialError::Unknown(name.into()))?;
        Self::from_toml(text, &format!("<embedded sim/materials/{name}.toml>"))
    }

    /// The same material on a different texel grid (patterns are in metres, so it looks the
    /// same, only sampled more finely or coarsely).
    pub fn with_texels(mut self, texels: usize) -> MaterialSpec {
        self.texels = texels;
        self
    }

    /// Every out-of-range value (empty when valid).
    pub fn validate(&self) -> Vec<MaterialError> {
        let mut e = Vec::new();
        let name = self.name.as_str();
        let bad = |e: &mut Vec<MaterialError>, field: String, v: String, allowed: &str| {
            e.push(MaterialError::OutOfRange { material: name.into(), field, value: v, allowed: allowed.into() })
        };
        if !(8..=4096).contains(&self.texels) {
            bad(&mut e, "texels".into(), self.texels.to_string(), "8..=4096");
        }
        let k = self.basis.len();
        if !(1..=16).contains(&k) {
            bad(&mut e, "basis".into(), format!("{k} spectra"), "1..=16 spectra");
        }
        for (i, l) in self.height.iter().enumerate() {
            if !(l.amplitude_m.is_finite() && l.amplitude_m.abs() <= 0.01) {
                bad(&mut e, format!("height[{i}].amplitude_m"), l.amplitude_m.to_string(), "[-0.01, 0.01] metres");
            }
            l.pattern.validate(name, &format!("height[{i}].pattern"), &mut e);
        }
        self.albedo.pattern.validate(name, "albedo.pattern", &mut e);
        if self.albedo.stops.is_empty() {
            bad(&mut e, "albedo.stops".into(), "[]".into(), "at least one weight vector");
        }
        for (i, s) in self.albedo.stops.iter().enumerate() {
            let sum: f64 = s.iter().sum();
            if s.len() != k || s.iter().any(|w| !(w.is_finite() && *w >= 0.0)) || sum > 1.0 + 1e-9 {
                bad(
                    &mut e,
                    format!("albedo.stops[{i}]"),
                    format!("{s:?}"),
                    &format!("{k} weights (one per basis spectrum), each >= 0, sum <= 1"),
                );
            }
        }
        if let Some(sp) = &self.specular {
            if !(0.0..=1.0).contains(&sp.strength) {
                bad(&mut e, "specular.strength".into(), sp.strength.to_string(), "[0, 1]");
            }
            if !(0.01..=1.0).contains(&sp.roughness) {
                bad(&mut e, "specular.roughness".into(), sp.roughness.to_string(), "[0.01, 1]");
            }
            if let Some(v) = &sp.vary {
                if !(0.0..=1.0).contains(&v.low) {
                    bad(&mut e, "specular.vary.low".into(), v.low.to_string(), "[0, 1]");
                }
                v.pattern.validate(name, "specular.vary.pattern", &mut e);
            }
        }
        e
    }
}

/// A generated material on an `N x N` texel grid spanning the sample square.
#[derive(Debug, Clone)]
pub struct Material {
    /// The spec it came from.
    pub spec: MaterialSpec,
    /// Texels per side, `N`.
    pub texels: usize,
    /// The height field (vertices at texel corners).
    pub height: HeightField,
    /// Basis weights per texel, `N * N * K`, row-major (row 0 at the `+y` edge).
    pub weights: Vec<f32>,
    /// Glossy strength per texel (`N * N`), all zero without a glossy lobe.
    pub glossy: Vec<f32>,
    /// GGX roughness of the glossy lobe.
    pub roughness: f64,
}

impl Material {
    /// Evaluates `spec` on its texel grid over a sample square of side `sample_side_m`
    /// centred on the origin. Heights: the layers' sum minus its mean (so the sample's mean
    /// plane is the plate plane `z = 0`), with the outermost vertex ring set to 0 so the
    /// surface meets the plate without a step.
    pub fn generate(spec: &MaterialSpec, sample_side_m: f64) -> Result<Material, MaterialError> {
        if let Some(e) = spec.validate().into_iter().next() {
            return Err(e);
        }
        let n = spec.texels;
        let dx = sample_side_m / n as f64;
        let half = sample_side_m / 2.0;
        let seed = spec.seed;
        let flat = spec.height.iter().all(|l| l.amplitude_m == 0.0);
        let mut h = vec![0.0; (n + 1) * (n + 1)];
        if !flat {
            for j in 0..=n {
                let y = half - j as f64 * dx;
                for i in 0..=n {
                    let x = -half + i as f64 * dx;
                    h[j * (n + 1) + i] = spec.height.iter().map(|l| l.amplitude_m * l.pattern.eval(seed, x, y)).sum();
                }
            }
            let mean = h.iter().sum::<f64>() / h.len() as f64;
            for j in 0..=n {
                for i in 0..=n {
                    let v = &mut h[j * (n + 1) + i];
                    *v = if i == 0 || j == 0 || i == n || j == n { 0.0 } else { *v - mean };
                }
            }
        }
        let height = HeightField::new(n, sample_side_m, h);
        let k = spec.basis.len();
        let stops = &spec.albedo.stops;
        let mut weights = vec![0.0f32; n * n * k];
        let mut glossy = vec![0.0f32; n * n];
        let (strength, roughness) = spec.specular.as_ref().map_or((0.0, 0.5), |s| (s.strength, s.roughness));
        for j in 0..n {
            let y = half - (j as f64 + 0.5) * dx;
            for i in 0..n {
                let x = -half + (i as f64 + 0.5) * dx;
                let v = spec.albedo.pattern.eval(seed, x, y);
                let w = interpolate_stops(stops, v);
                for (b, wb) in w.iter().enumerate() {
                    weights[(j * n + i) * k + b] = *wb as f32;
                }
                let g = match spec.specular.as_ref().and_then(|s| s.vary.as_ref()) {
                    Some(vary) => vary.low + (strength - vary.low) * vary.pattern.eval(seed, x, y),
                    None => strength,
                };
                glossy[j * n + i] = g as f32;
            }
        }
        Ok(Material { spec: spec.clone(), texels: n, height, weights, glossy, roughness })
    }
}

fn interpolate_stops(stops: &[Vec<f64>], v: f64) -> Vec<f64> {
    if stops.len() == 1 {
        return stops[0].clone();
    }
    let p = v.clamp(0.0, 1.0) * (stops.len() - 1) as f64;
    let i = (p.floor() as usize).min(stops.len() - 2);
    let f = p - i as f64;
    stops[i].iter().zip(&stops[i + 1]).map(|(a, b)| a + (b - a) * f).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shipped_material_file_parses_validates_and_generates() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../sim/materials");
        let mut count = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().and_then(|e| e.to_str()) != Some("toml") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let spec = MaterialSpec::from_toml(&text, &path.display().to_string()).unwrap();
            assert_eq!(Some(spec.name.as_str()), path.file_stem().and_then(|s| s.to_str()));
            assert!(BUILTIN_MATERIALS.iter().any(|(n, t)| *n == spec.name && *t == text), "{} not embedded", spec.name);
            let m = Material::generate(&spec.clone().with_texels(64), 0.1).unwrap();
            assert!(m.weights.iter().all(|w| w.is_finite() && *w >= 0.0));
            count += 1;
        }
        assert!(count >= 3);
    }

    #[test]
    fn bad_material_values_are_named() {
        let text = r#"
            name = "bad"
            texels = 4
            seed = 1
            basis = ["flat:0.5"]
            [[height]]
            amplitude_m = 0.5
            pattern = { kind = "noise", scale_m = -1.0 }
            [albedo]
            pattern = { kind = "constant", value = 0.5 }
            stops = [[0.7, 0.6]]
            [specular]
            strength = 2.0
            roughness = 0.001
        "#;
        let spec: MaterialSpec = toml::from_str(text).unwrap();
        let errs: Vec<String> = spec.validate().iter().map(|e| e.to_string()).collect();
        for f in [
            "texels",
            "height[0].amplitude_m",
            "height[0].pattern.scale_m",
            "albedo.stops[0]",
            "specular.strength",
            "specular.roughness",
        ] {
            assert!(errs.iter().any(|e| e.contains(&format!(" {f} = "))), "{f} not reported: {errs:#?}");
        }
        let unknown = toml::from_str::<MaterialSpec>(&text.replace("scale_m = -1.0", "scale_m = 1.0, sclae = 2"));
        assert!(unknown.unwrap_err().to_string().contains("sclae"));
    }

    #[test]
    fn patterns_stay_in_unit_range() {
        let pats = [
            Pattern::Noise { scale_m: 0.01, octaves: 5, gain: 0.6, salt: 3 },
            Pattern::Ridges { period_m: 0.003, angle_deg: 20.0, profile: RidgeProfile::Round, duty: 0.8 },
            Pattern::Wood { ring_m: 0.004, angle_deg: 5.0, warp_m: 0.003, warp_scale_m: 0.02, sharpness: 2.0 },
            Pattern::Tiles { tile_m: 0.025, grout_m: 0.002, bevel_m: 0.001 },
            Pattern::Cells { cell_m: 0.003, crease_m: 0.0006, salt: 0 },
        ];
        for p in &pats {
            let (mut lo, mut hi) = (1.0f64, 0.0f64);
            for k in 0..4000 {
                let x = (k as f64 * 0.618034).fract() * 0.1 - 0.05;
                let y = (k as f64 * 0.414214).fract() * 0.1 - 0.05;
                let v = p.eval(42, x, y);
                lo = lo.min(v);
                hi = hi.max(v);
            }
            assert!(lo >= 0.0 && hi <= 1.0 && hi - lo > 0.3, "{p:?}: range [{lo}, {hi}]");
        }
    }
}
