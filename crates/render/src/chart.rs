//! Colour charts for colour calibration as the simulator renders them: a flat, matte chart
//! mounted in the sample region of the holder plate (so the plate's markers register it like
//! any sample).
//!
//! The layout and published references (rows, columns, pitch, gap, patch names and L*a*b*
//! D50) are [`btfrig_color::chart::ChartLayout`], which the calibration procedure uses on any
//! rig; a [`ColorChart`] adds what only rendering needs, a reflectance spectrum per patch.
//! Two charts are built in:
//!
//! * [`ColorChart::colorchecker24`]: ColorChecker Classic, 4 x 6, the Ohta / ISO 17321-1
//!   spectra of [`spectral::colorchecker24`] with the published Lab of the edition made after
//!   November 2014;
//! * [`ColorChart::colorchecker_sg140`]: ColorChecker SG, 10 x 14, whose published data
//!   (`sim/spectra/colorcheckersg140_lab_d50.csv`) is Lab only: each patch gets a synthetic
//!   smooth reflectance that reproduces its XYZ under CIE D50 ([`synthesise_reflectance`]:
//!   least squares with a curvature penalty, bounded to `[0, 1]`), the fit error recorded in
//!   [`ChartPatch::synthesis_delta_e76`].

use std::sync::LazyLock;

pub use btfrig_color::chart::{ChartLayout, PatchReference, CHART_NAMES};
use btfrig_color::delta_e_76;
use btfrig_color::space::{lab_to_xyz, xyz_to_lab};
use btfrig_core::config::plate::PlateConfig;
use nalgebra::{DMatrix, DVector};

use crate::colour::ColourSystem;
use crate::material::MaterialSpec;
use crate::scene::{Resolver, Scene, SceneError};
use crate::spectral::{self, Spectrum, LEN};

/// Reflectance of the chart's black gaps and surround (matte black paint, ~3%).
pub const GAP_REFLECTANCE: f64 = 0.03;

/// Texels per side of the chart's texture over the sample region: 0.1 mm on the default
/// 0.1 m sample, a quarter of a default camera pixel, so a patch edge blurs by one texel.
pub const CHART_TEXELS: usize = 1000;

/// What the renderer needs of one patch (its name and published Lab are the layout's
/// [`PatchReference`] of the same index).
#[derive(Debug, Clone, PartialEq)]
pub struct ChartPatch {
    /// Spectral reflectance (measured, or synthesised from the Lab for the SG chart).
    pub spectrum: Spectrum,
    /// ΔE*ab between the published Lab and the Lab of `spectrum` under CIE D50: the synthesis
    /// error for synthetic spectra (for measured spectra the two come from different charts).
    pub synthesis_delta_e76: f64,
}

/// A colour chart to render: layout and references, and a spectrum per patch.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorChart {
    /// Layout and published references.
    pub layout: ChartLayout,
    /// One per layout patch, same order.
    pub patches: Vec<ChartPatch>,
}

impl ColorChart {
    /// ColorChecker Classic 24 (4 x 6), 16 mm pitch and 3 mm gaps: 96 x 64 mm in the default
    /// 100 mm sample region.
    pub fn colorchecker24() -> ColorChart {
        let d50 = d50_system();
        let white = d50.lamp_white_xyz();
        let layout = ChartLayout::colorchecker24();
        let patches = spectral::colorchecker24()
            .iter()
            .zip(&layout.patches)
            .map(|(s, r)| ChartPatch {
                spectrum: *s,
                synthesis_delta_e76: delta_e_76(xyz_to_lab(d50.xyz(s), white), r.lab_d50),
            })
            .collect();
        ColorChart { layout, patches }
    }

    /// ColorChecker SG (10 x 14), 7 mm pitch and 1.5 mm gaps: 98 x 70 mm. Spectra synthesised
    /// from the published Lab (computed once, on first use).
    pub fn colorchecker_sg140() -> ColorChart {
        ColorChart { layout: ChartLayout::colorchecker_sg140(), patches: SG140.clone() }
    }

    /// A built-in chart by name ([`CHART_NAMES`]).
    pub fn by_name(name: &str) -> Result<ColorChart, String> {
        match name {
            "colorchecker24" => Ok(Self::colorchecker24()),
            "colorchecker-sg140" => Ok(Self::colorchecker_sg140()),
            _ => Err(ChartLayout::by_name(name).expect_err("every built-in layout has spectra")),
        }
    }
}

/// The colour system of CIE D50 light (the camera is irrelevant for XYZ).
fn d50_system() -> ColourSystem {
    ColourSystem::new("D50", spectral::camera_names()[0]).expect("embedded D50 and camera data")
}

static SG140: LazyLock<Vec<ChartPatch>> = LazyLock::new(|| {
    let d50 = d50_system();
    let white = d50.lamp_white_xyz();
    let weights = d50_xyz_weights();
    ChartLayout::colorchecker_sg140()
        .patches
        .iter()
        .map(|r| {
            // Lab relative to the spectral D50 white, so that the Lab (not just the XYZ) is kept.
            let target = lab_to_xyz(r.lab_d50, white);
            let spectrum = synthesise_reflectance(&weights, target);
            ChartPatch { spectrum, synthesis_delta_e76: delta_e_76(xyz_to_lab(d50.xyz(&spectrum), white), r.lab_d50) }
        })
        .collect()
});

/// The XYZ weights of CIE D50 (`E x̄ / Σ E ȳ`, ...): `XYZ = weights · ρ`.
fn d50_xyz_weights() -> [Spectrum; 3] {
    let e = spectral::lamp_spectrum("D50").expect("embedded D50");
    let cmf = spectral::cie1931_cmf();
    let y = e.dot(&cmf[1]);
    cmf.map(|s| e.mul(&s).scale(1.0 / y))
}

/// Relative weight of the curvature penalty against the XYZ residual (XYZ of order 1).
const SMOOTHNESS: f64 = 1e-5;

/// A smooth reflectance in `[0, 1]` whose tristimulus values under `weights` (`XYZ_k =
/// weights_k · ρ`) are `target`: minimises `|W ρ - t|² + SMOOTHNESS |D² ρ|²` (second
/// differences) subject to `0 <= ρ <= 1` by a primal active-set method (exact; the problem
/// is a strictly convex 41-variable QP). A target outside the gamut of `[0, 1]` reflectances
/// gets the nearest reachable colour.
pub fn synthesise_reflectance(weights: &[Spectrum; 3], target: [f64; 3]) -> Spectrum {
    let n = LEN;
    // H = Wᵀ W + s DᵀD, c = Wᵀ t: minimise ½ρᵀHρ - cᵀρ.
    let mut h = DMatrix::<f64>::zeros(n, n);
    let mut c = DVector::<f64>::zeros(n);
    for (k, w) in weights.iter().enumerate() {
        for i in 0..n {
            c[i] += w.0[i] * target[k];
            for j in 0..n {
                h[(i, j)] += w.0[i] * w.0[j];
            }
        }
    }
    for i in 1..n - 1 {
        let d = [(i - 1, 1.0), (i, -2.0), (i + 1, 1.0)];
        for &(a, va) in &d {
            for &(b, vb) in &d {
                h[(a, b)] += SMOOTHNESS * va * vb;
            }
        }
    }
    // 0: free, -1: at 0, +1: at 1.
    let mut state = vec![0i8; n];
    let mut x = DVector::from_element(n, 0.5);
    for _ in 0..400 {
        let free: Vec<usize> = (0..n).filter(|&i| state[i] == 0).collect();
        // Solve the subproblem on the free set with the others held at their bounds.
        let mut cand = x.clone();
        for i in 0..n {
            if state[i] != 0 {
                cand[i] = if state[i] > 0 { 1.0 } else { 0.0 };
            }
        }
        if !free.is_empty() {
            let hf = DMatrix::from_fn(free.len(), free.len(), |a, b| h[(free[a], free[b])]);
            let rhs = DVector::from_fn(free.len(), |a, _| {
                let i = free[a];
                c[i] - (0..n).filter(|&j| state[j] != 0).map(|j| h[(i, j)] * cand[j]).sum::<f64>()
            });
            let sol = hf.lu().solve(&rhs).unwrap_or_else(|| DVector::from_element(free.len(), 0.5));
            for (a, &i) in free.iter().enumerate() {
                cand[i] = sol[a];
            }
        }
        // Step towards the candidate as far as the bounds allow.
        let mut alpha = 1.0;
        let mut block = None;
        for &i in &free {
            let d = cand[i] - x[i];
            let room = if d < 0.0 {
                -x[i] / d
            } else if d > 0.0 {
                (1.0 - x[i]) / d
            } else {
                f64::INFINITY
            };
            if room < alpha {
                alpha = room;
                block = Some((i, if d < 0.0 { -1 } else { 1 }));
            }
        }
        x += (&cand - &x) * alpha.max(0.0);
        if let Some((i, s)) = block {
            state[i] = s;
            x[i] = if s > 0 { 1.0 } else { 0.0 };
            continue;
        }
        // At the subproblem's optimum: release the bound whose multiplier has the wrong sign.
        let g = &h * &x - &c;
        let worst = (0..n)
            .filter(|&i| state[i] != 0)
            .map(|i| (i, if state[i] < 0 { g[i] } else { -g[i] }))
            .filter(|&(_, lambda)| lambda < -1e-14)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, _)) => state[i] = 0,
            None => break,
        }
    }
    Spectrum(std::array::from_fn(|i| x[i].clamp(0.0, 1.0)))
}

/// The scene of `chart` mounted in the sample region of `plate`: the plate with its markers,
/// the chart as a flat matte "material" whose texels take the patch colours (`colours[k]`:
/// camera RGB and output RGB of patch `k`) and `gap` elsewhere.
pub fn chart_scene(
    plate: &PlateConfig,
    chart: &ColorChart,
    colours: &[([f64; 3], [f64; 3])],
    gap: ([f64; 3], [f64; 3]),
    resolve: &Resolver,
) -> Result<Scene, SceneError> {
    let spec = MaterialSpec::from_toml(
        &format!(
            "name = \"{}\"\ntexels = {CHART_TEXELS}\nseed = 0\nbasis = [\"flat:0\"]\n\
             [albedo]\npattern = {{ kind = \"constant\", value = 0.0 }}\nstops = [[1.0]]\n",
            chart.layout.name
        ),
        "<colour chart placeholder material>",
    )?;
    let mut scene = Scene::build(plate, &spec, resolve)?;
    let mut problems = chart.layout.problems(scene.layout.sample_side_m);
    if chart.patches.len() != chart.layout.patches.len() {
        problems.push(format!("{} spectra for {} patches", chart.patches.len(), chart.layout.patches.len()));
    }
    if !problems.is_empty() {
        return Err(SceneError::Colour {
            field: "chart".into(),
            name: chart.layout.name.clone(),
            message: problems.join("; "),
        });
    }
    let n = scene.material.texels;
    let side = scene.layout.sample_side_m;
    let texel = side / n as f64;
    for row in 0..n {
        let y = side / 2.0 - (row as f64 + 0.5) * texel;
        for col in 0..n {
            let x = -side / 2.0 + (col as f64 + 0.5) * texel;
            let (cam, out) = chart.layout.patch_at(x, y).map_or(gap, |k| colours[k]);
            scene.albedo[0][row * n + col] = cam.map(|v| v as f32);
            scene.albedo[1][row * n + col] = out.map(|v| v as f32);
        }
    }
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The synthetic SG spectra reproduce the published Lab under D50, stay in [0, 1] and are
    /// smooth (no 10 nm step larger than 0.2).
    #[test]
    fn sg140_synthesis_reproduces_published_lab() {
        let c = ColorChart::colorchecker_sg140();
        assert_eq!(c.patches.len(), 140);
        assert_eq!(c.layout.patches[0].name, "A1");
        let errs: Vec<f64> = c.patches.iter().map(|p| p.synthesis_delta_e76).collect();
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        let max = errs.iter().cloned().fold(0.0, f64::max);
        eprintln!("SG140 synthesis: mean dE76 {mean:.2e}, max {max:.2e}");
        assert!(max < 0.05, "max synthesis error {max}");
        for (p, r) in c.patches.iter().zip(&c.layout.patches) {
            assert!(p.spectrum.0.iter().all(|v| (0.0..=1.0).contains(v)));
            let step = p.spectrum.0.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
            assert!(step < 0.2, "{}: step {step}", r.name);
        }
    }

    /// The solver against a case with a known answer: a grey's XYZ gives back the grey (flat
    /// spectra have zero curvature), and an unreachable target is clamped into [0, 1].
    #[test]
    fn synthesis_of_a_grey_is_flat() {
        let w = d50_xyz_weights();
        let grey = Spectrum::constant(0.37);
        let xyz = w.map(|s| s.dot(&grey));
        let s = synthesise_reflectance(&w, xyz);
        assert!(s.0.iter().all(|v| (v - 0.37).abs() < 1e-6), "{:?}", s.0);
        let s = synthesise_reflectance(&w, [3.0, 3.0, 3.0]);
        assert!(s.0.iter().all(|v| (v - 1.0).abs() < 1e-12));
    }
}
