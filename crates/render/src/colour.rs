//! Colour: what the simulated camera records, and what the "true" colour is.
//!
//! Brief overview: a [`ColourSystem`] pairs a lamp spectrum with a camera's spectral
//! sensitivities. For a spectral reflectance ρ(λ) (sums over the 380–780 nm, 10 nm grid; `E`
//! the lamp's relative spectrum):
//!
//! * [`ColourSystem::camera_rgb`]: `c_k = Σ E ρ S_k / Σ E S_G`, the camera's raw response,
//!   normalised so that a perfect white reflector (ρ = 1) gives green = 1;
//! * [`ColourSystem::output_rgb`]: the project's ground-truth colour space, **linear sRGB
//!   (Rec. 709 primaries, D65 white) of the reflected light, chromatically adapted**:
//!   `XYZ = Σ E ρ (x̄, ȳ, z̄) / Σ E ȳ` (lamp white has Y = 1), Bradford-adapted from the lamp's
//!   white to D65, then converted to linear sRGB. A perfect white reflector is exactly
//!   (1, 1, 1) under any lamp, so the output colour is the object's colour as a person adapted
//!   to the lamp sees it.
//!
//! Both are linear in ρ. The camera's sensitivities are not a linear transform of the CIE
//! observer's, so no 3x3 matrix maps one to the other exactly:
//! [`ColourSystem::fit_camera_to_output`] finds the least-squares matrix over a set of
//! reflectances (the 24 ColorChecker patches) and reports the residuals (`docs/color.md`).
//!
//! The colour-space conversions (sRGB, XYZ, L*a*b*, Bradford) are `btfrig_color::space`'s;
//! this module holds what only the simulator has: the lamp and the camera's spectra.

use btfrig_color::delta_e_76;
use btfrig_color::space::{bradford, d65_white, linear_srgb_to_lab, mat3_apply, mat3_mul, xyz_to_srgb_matrix, Mat3};
use nalgebra::{Matrix3, Vector3};

use crate::spectral::{self, SpectralError, Spectrum};

/// A lamp spectrum paired with a camera's sensitivities and the CIE 1931 observer.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourSystem {
    /// Camera weights `E S_k / Σ E S_G`.
    camera_weights: [Spectrum; 3],
    /// Observer weights `E (x̄, ȳ, z̄) / Σ E ȳ`.
    xyz_weights: [Spectrum; 3],
    /// XYZ of the perfect white reflector under the lamp (Y = 1).
    lamp_white: [f64; 3],
    /// XYZ (lamp-relative) to output linear sRGB: XYZ->sRGB after Bradford lamp white -> D65.
    xyz_to_output: [[f64; 3]; 3],
    /// `Σ E S_G / (max S · Σ E)`.
    green_efficiency: f64,
    /// Wavelength of the largest camera sensitivity sample, nm.
    peak_nm: f64,
}

impl ColourSystem {
    /// The system of lamp spectrum `lamp` (a column of `illuminants_10nm.csv`) and camera
    /// `camera` (see [`spectral::camera_names`]).
    pub fn new(lamp: &str, camera: &str) -> Result<Self, SpectralError> {
        Ok(Self::from_spectra(&spectral::lamp_spectrum(lamp)?, &spectral::camera_sensitivity(camera)?))
    }

    /// The system of the `[lamp]` and `[sensor]` sections of a rig config.
    pub fn from_config(
        lamp: &btfrig_core::config::lamp::LampConfig,
        sensor: &btfrig_core::config::sensor::SensorConfig,
    ) -> Result<Self, SpectralError> {
        Self::new(&lamp.spectrum, &sensor.camera_sensitivity)
    }

    /// The system of arbitrary spectra (the lamp's scale does not matter).
    pub fn from_spectra(lamp: &Spectrum, camera: &[Spectrum; 3]) -> Self {
        let cmf = spectral::cie1931_cmf();
        let g = lamp.dot(&camera[1]);
        let y = lamp.dot(&cmf[1]);
        let camera_weights = camera.map(|s| lamp.mul(&s).scale(1.0 / g));
        let xyz_weights = cmf.map(|s| lamp.mul(&s).scale(1.0 / y));
        let lamp_white = xyz_weights.map(|w| w.sum());
        let adapt = bradford(lamp_white, d65_white());
        let xyz_to_output = mat3_mul(&xyz_to_srgb_matrix(), &adapt);
        let (peak, peak_nm) =
            camera.iter().map(|s| s.peak()).fold((f64::NEG_INFINITY, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        ColourSystem {
            camera_weights,
            xyz_weights,
            lamp_white,
            xyz_to_output,
            green_efficiency: g / (peak * lamp.sum()),
            peak_nm,
        }
    }

    /// Camera RGB response to reflectance `r`; a perfect white reflector gives green = 1.
    pub fn camera_rgb(&self, r: &Spectrum) -> [f64; 3] {
        self.camera_weights.map(|w| w.dot(r))
    }

    /// CIE XYZ of the light reflected by `r` under the lamp, scaled so the lamp's white has
    /// Y = 1 (not adapted).
    pub fn xyz(&self, r: &Spectrum) -> [f64; 3] {
        self.xyz_weights.map(|w| w.dot(r))
    }

    /// XYZ of a perfect white reflector under the lamp (Y = 1).
    pub fn lamp_white_xyz(&self) -> [f64; 3] {
        self.lamp_white
    }

    /// Output colour (linear sRGB, D65, adapted from the lamp white; see the module docs).
    pub fn output_rgb(&self, r: &Spectrum) -> [f64; 3] {
        mat3_apply(&self.xyz_to_output, self.xyz(r))
    }

    /// The matrix taking lamp-relative XYZ ([`ColourSystem::xyz`]) to output RGB.
    pub fn xyz_to_output_matrix(&self) -> [[f64; 3]; 3] {
        self.xyz_to_output
    }

    /// Camera RGB of a perfect white reflector (`[r, 1, b]`).
    pub fn camera_white(&self) -> [f64; 3] {
        self.camera_rgb(&Spectrum::constant(1.0))
    }

    /// Per-channel multipliers that make a perfect white reflector (1, 1, 1) in camera RGB.
    pub fn white_balance(&self) -> [f64; 3] {
        self.camera_white().map(|v| 1.0 / v)
    }

    /// Lamp-weighted green efficiency `Σ E S_G / (max S · Σ E)`: the green channel's response
    /// to the lamp's light relative to the camera's peak responsivity (used by
    /// [`crate::sensor::electrons_per_second_scale`]).
    pub fn lamp_green_efficiency(&self) -> f64 {
        self.green_efficiency
    }

    /// Wavelength (nm) at which the camera's most sensitive channel peaks.
    pub fn camera_peak_wavelength_nm(&self) -> f64 {
        self.peak_nm
    }

    /// The 3x3 matrix `M` that best maps white-balanced camera RGB (`wb ⊙ camera_rgb`) to
    /// output RGB over `patches`, in the least-squares sense; with `white_preserving` each row
    /// is constrained to sum to 1, so white stays exactly white (the usual choice for a colour
    /// correction matrix). Residuals are reported over the same patches.
    pub fn fit_camera_to_output(&self, patches: &[Spectrum], white_preserving: bool) -> CameraMatrixFit {
        let wb = self.white_balance();
        let cams: Vec<Vector3<f64>> = patches
            .iter()
            .map(|p| {
                let c = self.camera_rgb(p);
                Vector3::new(c[0] * wb[0], c[1] * wb[1], c[2] * wb[2])
            })
            .collect();
        let outs: Vec<Vector3<f64>> = patches.iter().map(|p| Vector3::from(self.output_rgb(p))).collect();
        // Normal equations: (AᵀA) mᵣ = Aᵀ bᵣ for each output row r, A = camera rows.
        let ata: Matrix3<f64> = cams.iter().map(|c| c * c.transpose()).sum();
        let ata_inv = ata.try_inverse().expect("at least three independent patches");
        let mut m = Matrix3::zeros();
        for r in 0..3 {
            let atb: Vector3<f64> = cams.iter().zip(&outs).map(|(c, o)| c * o[r]).sum();
            let mut row = ata_inv * atb;
            if white_preserving {
                // Lagrange multiplier for 1ᵀ row = 1.
                let ones = Vector3::new(1.0, 1.0, 1.0);
                let g = ata_inv * ones;
                row += g * ((1.0 - ones.dot(&row)) / ones.dot(&g));
            }
            m.set_row(r, &row.transpose());
        }
        let matrix: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
        let mut fit = CameraMatrixFit { matrix, white_balance: wb, ..Default::default() };
        let n = patches.len() as f64;
        for (c, o) in cams.iter().zip(&outs) {
            let pred = m * c;
            let e = (pred - o).norm();
            fit.mean_rgb_error += e / n;
            fit.rms_rgb_error += e * e / n;
            fit.max_rgb_error = fit.max_rgb_error.max(e);
            let de = delta_e_76(linear_srgb_to_lab(pred.into()), linear_srgb_to_lab((*o).into()));
            fit.mean_delta_e76 += de / n;
            fit.max_delta_e76 = fit.max_delta_e76.max(de);
        }
        fit.rms_rgb_error = fit.rms_rgb_error.sqrt();
        fit
    }

    /// [`ColourSystem::fit_camera_to_output`] over the 24 ColorChecker patches (Ohta), white
    /// preserving: the matrix the preview uses.
    pub fn colorchecker_matrix(&self) -> CameraMatrixFit {
        self.fit_camera_to_output(spectral::colorchecker24(), true)
    }
}

/// A camera-to-output matrix and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CameraMatrixFit {
    /// Output RGB = `matrix` · (`white_balance` ⊙ camera RGB).
    pub matrix: [[f64; 3]; 3],
    /// Per-channel white balance applied before the matrix.
    pub white_balance: [f64; 3],
    /// Mean Euclidean error in linear output RGB.
    pub mean_rgb_error: f64,
    /// Root-mean-square Euclidean error in linear output RGB.
    pub rms_rgb_error: f64,
    /// Largest Euclidean error in linear output RGB.
    pub max_rgb_error: f64,
    /// Mean CIE 1976 ΔE*ab (L*a*b* under D65).
    pub mean_delta_e76: f64,
    /// Largest ΔE*ab.
    pub max_delta_e76: f64,
}

impl CameraMatrixFit {
    /// Output RGB of a camera RGB triple.
    pub fn apply(&self, camera_rgb: [f64; 3]) -> [f64; 3] {
        let wb: [f64; 3] = std::array::from_fn(|i| camera_rgb[i] * self.white_balance[i]);
        mat3_apply(&self.matrix, wb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectral::{colorchecker24, colorchecker24_reference};
    use btfrig_color::space::xyz_to_lab;

    fn sys(lamp: &str) -> ColourSystem {
        ColourSystem::new(lamp, "nikon_d5100").unwrap()
    }

    #[test]
    fn white_is_exactly_one_under_every_lamp_and_camera() {
        for lamp in spectral::lamp_spectrum_names() {
            for cam in spectral::camera_names() {
                let s = ColourSystem::new(lamp, cam).unwrap();
                let w = s.output_rgb(&Spectrum::constant(1.0));
                assert!(w.iter().all(|v| (v - 1.0).abs() < 1e-12), "{lamp} {cam}: {w:?}");
                assert!((s.camera_white()[1] - 1.0).abs() < 1e-12);
                assert!((s.lamp_white_xyz()[1] - 1.0).abs() < 1e-12);
            }
        }
    }

    /// Lab of the chart spectra under a D50 lamp against the published (measured) chart Lab.
    #[test]
    fn colorchecker_under_d50_matches_published_lab() {
        let s = sys("D50");
        let white = s.lamp_white_xyz();
        // The computed D50 white equals ICC D50 closely.
        assert!((white[0] - 0.9642).abs() < 2e-3 && (white[2] - 0.8249).abs() < 2e-3, "{white:?}");
        let refs = colorchecker24_reference();
        let des: Vec<f64> = colorchecker24()
            .iter()
            .zip(refs)
            .map(|(p, r)| delta_e_76(xyz_to_lab(s.xyz(p), white), r.lab_d50))
            .collect();
        let mean = des.iter().sum::<f64>() / 24.0;
        let max = des.iter().cloned().fold(0.0, f64::max);
        eprintln!("Ohta spectra vs published Lab (D50): mean dE76 {mean:.2}, max {max:.2}");
        // Spectra and Lab come from different physical charts (data README: ~1.2 dE00 mean
        // floor); ΔE76 runs higher than ΔE00 on saturated colours.
        assert!(mean < 3.0 && max < 8.0, "mean {mean} max {max}");
        // Output RGB under D50 follows the same Bradford path as the published sRGB.
        let rgb_err: f64 = colorchecker24()
            .iter()
            .zip(refs)
            .map(|(p, r)| {
                let o = s.output_rgb(p);
                (0..3).map(|i| (o[i] - r.srgb_linear[i]).abs()).fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        eprintln!("max |output_rgb - published sRGB_lin| under D50: {rgb_err:.4}");
        assert!(rgb_err < 0.05, "{rgb_err}");
    }

    #[test]
    fn greys_are_neutral_and_proportional_in_camera_rgb() {
        let s = sys("LS_Metal_Halide");
        let wb = s.white_balance();
        let cc = colorchecker24();
        for p in &cc[18..24] {
            let c = s.camera_rgb(p);
            let balanced: Vec<f64> = (0..3).map(|i| c[i] * wb[i]).collect();
            // Neutral: balanced channels agree within 5% (the chart's greys are not flat).
            let mean = balanced.iter().sum::<f64>() / 3.0;
            assert!(balanced.iter().all(|v| (v / mean - 1.0).abs() < 0.05), "{balanced:?}");
            // Proportional to the patch's mean reflectance over the visible range.
            let refl = p.0[5..36].iter().sum::<f64>() / 31.0; // 430..730 nm
            assert!((c[1] / refl - 1.0).abs() < 0.05, "{} vs {refl}", c[1]);
        }
    }

    #[test]
    fn responses_are_linear() {
        let s = sys("A");
        let (a, b) = (colorchecker24()[2], colorchecker24()[11]);
        let mix = Spectrum(std::array::from_fn(|i| 0.3 * a.0[i] + 1.7 * b.0[i]));
        let (ca, cb, cm) = (s.camera_rgb(&a), s.camera_rgb(&b), s.camera_rgb(&mix));
        let (oa, ob, om) = (s.output_rgb(&a), s.output_rgb(&b), s.output_rgb(&mix));
        for i in 0..3 {
            assert!((cm[i] - (0.3 * ca[i] + 1.7 * cb[i])).abs() < 1e-12);
            assert!((om[i] - (0.3 * oa[i] + 1.7 * ob[i])).abs() < 1e-12);
        }
    }

    #[test]
    fn camera_differs_from_observer_by_a_realistic_matrix() {
        for cam in spectral::camera_names() {
            let s = ColourSystem::new("LS_Metal_Halide", cam).unwrap();
            let free = s.fit_camera_to_output(colorchecker24(), false);
            let white = s.colorchecker_matrix();
            eprintln!(
                "{cam}: free fit mean dE76 {:.2} max {:.2} rgb mean {:.4} max {:.4}; white-preserving mean dE76 {:.2} max {:.2} rgb mean {:.4} max {:.4}\n  M = {:?}",
                free.mean_delta_e76, free.max_delta_e76, free.mean_rgb_error, free.max_rgb_error,
                white.mean_delta_e76, white.max_delta_e76, white.mean_rgb_error, white.max_rgb_error, white.matrix
            );
            // Not the observer (a residual remains), but close (a real camera is usable).
            assert!(free.mean_delta_e76 > 0.2 && free.mean_delta_e76 < 5.0);
            assert!(white.mean_delta_e76 >= free.mean_delta_e76 * 0.8);
            // White-preserving rows sum to 1 and map white exactly.
            let w = white.apply(s.camera_white());
            assert!(w.iter().all(|v| (v - 1.0).abs() < 1e-12), "{w:?}");
            // Least squares: no nearby matrix does better (perturb each entry).
            for r in 0..3 {
                for c in 0..3 {
                    for d in [-1e-3, 1e-3] {
                        let mut m = free;
                        m.matrix[r][c] += d;
                        let sse = |f: &CameraMatrixFit| -> f64 {
                            colorchecker24()
                                .iter()
                                .map(|p| {
                                    let pr = f.apply(s.camera_rgb(p));
                                    let o = s.output_rgb(p);
                                    (0..3).map(|i| (pr[i] - o[i]).powi(2)).sum::<f64>()
                                })
                                .sum()
                        };
                        assert!(sse(&m) > sse(&free));
                    }
                }
            }
        }
    }

    #[test]
    fn rgb_reflectance_whites_and_greys_map_to_neutral_output() {
        let s = sys("LS_Metal_Halide");
        let o = s.output_rgb(&Spectrum::from_rgb_reflectance([0.5, 0.5, 0.5]));
        assert!(o.iter().all(|v| (v - 0.5).abs() < 1e-12));
        let red = s.output_rgb(&Spectrum::from_rgb_reflectance([0.8, 0.1, 0.1]));
        assert!(red[0] > 2.0 * red[1] && red[0] > 2.0 * red[2], "{red:?}");
    }
}
