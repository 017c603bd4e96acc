//! A scene: the holder plate plus a generated material, with every colour resolved.
//!
//! Rendering is linear in reflectance, so each basis spectrum is reduced to two RGB
//! triples: its camera-RGB response (what the sensor sees, for the rendered frame) and its
//! output colour (linear sRGB, D65-relative, for the ground truth). A caller-supplied
//! resolver maps a spectrum name (e.g. `"colorchecker:dark skin"`, `"flat:0.8"`) to
//! `(camera, output)`; the colour system normalises both so that a white reflector gives
//! camera green 1 and output (1, 1, 1).

use btfrig_core::config::plate::PlateConfig;
use btfrig_core::ConfigError;

use crate::material::{Material, MaterialError, MaterialSpec};
use crate::plate::PlateLayout;
use btfrig_core::config::target::TargetBoard;

/// Maps a spectrum name to its `(camera RGB, output RGB)` response, or says why it cannot.
pub type Resolver<'a> = dyn Fn(&str) -> Result<([f64; 3], [f64; 3]), String> + 'a;

/// Which colour space a shading result is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColourSpace {
    /// The camera's RGB signal (for frames).
    Camera = 0,
    /// Linear sRGB, D65-relative (for ground truth).
    Output = 1,
}

/// The resolved colours of a material's basis spectra.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisColours {
    /// Camera-RGB response of each basis spectrum.
    pub camera: Vec<[f32; 3]>,
    /// Output (linear sRGB) colour of each basis spectrum.
    pub output: Vec<[f32; 3]>,
}

/// A problem building a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The `[plate]` section is invalid.
    #[error(transparent)]
    Plate(#[from] ConfigError),
    /// The material is invalid.
    #[error(transparent)]
    Material(#[from] MaterialError),
    /// A spectrum name could not be resolved to colours.
    #[error("{field} = {name:?}: {message}")]
    Colour {
        /// Where the name was used, e.g. `corduroy.basis[2]` or `plate.albedo`.
        field: String,
        /// The spectrum name.
        name: String,
        /// The resolver's explanation.
        message: String,
    },
}

/// Plate, material and resolved colours: everything the renderer reads.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Plate geometry and markers.
    pub layout: PlateLayout,
    /// The generated material.
    pub material: Material,
    /// Resolved colours of the material's basis spectra.
    pub basis: BasisColours,
    /// Per colour space, per texel: diffuse albedo `(1 - glossy) * sum_k w_k basis_k`.
    pub(crate) albedo: [Vec<[f32; 3]>; 2],
    /// Per colour space: colour of the glossy lobe (times the per-texel strength).
    pub(crate) glossy_colour: [[f64; 3]; 2],
    /// Per colour space: plate (and white module) albedo.
    pub(crate) plate: [[f64; 3]; 2],
    /// Per colour space: black module albedo.
    pub(crate) black: [[f64; 3]; 2],
}

impl Scene {
    /// Builds the scene: validates the plate, generates the material on the plate's sample
    /// square, resolves every spectrum name.
    pub fn build(plate: &PlateConfig, material: &MaterialSpec, resolve: &Resolver) -> Result<Scene, SceneError> {
        let layout = PlateLayout::new(plate)?;
        Self::build_with_layout(layout, material, &plate.albedo, &plate.marker_black, resolve)
    }

    /// A scene of a calibration board ([`TargetBoard`]) mounted in place of the plate: no
    /// sample (a flat, never-hit placeholder material keeps the renderer's paths uniform).
    pub fn build_target(board: &TargetBoard, resolve: &Resolver) -> Result<Scene, SceneError> {
        let layout = PlateLayout::target(board)?;
        let spec = MaterialSpec::from_toml(
            "name = \"calibration-board\"\ntexels = 8\nseed = 0\nbasis = [\"flat:0\"]\n\
             [albedo]\npattern = { kind = \"constant\", value = 0.0 }\nstops = [[1.0]]\n",
            "<calibration board placeholder material>",
        )?;
        Self::build_with_layout(layout, &spec, &board.albedo, &board.marker_black, resolve)
    }

    fn build_with_layout(
        layout: PlateLayout,
        material: &MaterialSpec,
        albedo_name: &str,
        black_name: &str,
        resolve: &Resolver,
    ) -> Result<Scene, SceneError> {
        // A board has no sample region; its placeholder material spans a tiny square.
        let material = Material::generate(material, layout.sample_side_m.max(1e-6))?;
        let res = |field: String, name: &str| {
            resolve(name).map_err(|message| SceneError::Colour { field, name: name.into(), message })
        };
        let mut basis = BasisColours { camera: Vec::new(), output: Vec::new() };
        for (k, name) in material.spec.basis.iter().enumerate() {
            let (c, o) = res(format!("{}.basis[{k}]", material.spec.name), name)?;
            basis.camera.push(c.map(|v| v as f32));
            basis.output.push(o.map(|v| v as f32));
        }
        let gname = material.spec.specular.as_ref().map_or("flat:1", |s| s.colour.as_str()).to_string();
        let (gc, go) = res(format!("{}.specular.colour", material.spec.name), &gname)?;
        let (pc, po) = res("plate.albedo".into(), albedo_name)?;
        let (bc, bo) = res("plate.marker_black".into(), black_name)?;
        let n = material.texels;
        let k = basis.camera.len();
        let mut albedo = [vec![[0.0f32; 3]; n * n], vec![[0.0f32; 3]; n * n]];
        for (t, &glossy) in material.glossy.iter().enumerate() {
            let w = &material.weights[t * k..(t + 1) * k];
            let diffuse = 1.0 - glossy as f64;
            for (space, cols) in [&basis.camera, &basis.output].into_iter().enumerate() {
                let mut acc = [0.0f64; 3];
                for (wb, col) in w.iter().zip(cols) {
                    for ch in 0..3 {
                        acc[ch] += *wb as f64 * col[ch] as f64;
                    }
                }
                albedo[space][t] = acc.map(|a| (a * diffuse) as f32);
            }
        }
        Ok(Scene { layout, material, basis, albedo, glossy_colour: [gc, go], plate: [pc, po], black: [bc, bo] })
    }

    /// Diffuse albedo at sample point `(x, y)` (bilinear between texel centres) and glossy
    /// strength, in `space`.
    pub(crate) fn texel_reflectance(&self, x: f64, y: f64, space: ColourSpace) -> ([f64; 3], f64) {
        let n = self.material.texels;
        let half = self.layout.sample_side_m / 2.0;
        let texel = self.layout.sample_side_m / n as f64;
        let gx = ((x + half) / texel - 0.5).clamp(0.0, (n - 1) as f64);
        let gy = ((half - y) / texel - 0.5).clamp(0.0, (n - 1) as f64);
        let i = (gx.floor() as usize).min(n.saturating_sub(2));
        let j = (gy.floor() as usize).min(n.saturating_sub(2));
        let (s, u) = (gx - i as f64, gy - j as f64);
        let w = [(1.0 - s) * (1.0 - u), s * (1.0 - u), (1.0 - s) * u, s * u];
        let idx = [j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1];
        let alb = &self.albedo[space as usize];
        let mut a = [0.0; 3];
        let mut g = 0.0;
        for k in 0..4 {
            for ch in 0..3 {
                a[ch] += w[k] * alb[idx[k]][ch] as f64;
            }
            g += w[k] * self.material.glossy[idx[k]] as f64;
        }
        (a, g)
    }
}
