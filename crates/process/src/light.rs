//! Light calibration and lamp drift in the pipeline.
//!
//! With a [`LightCorrection`] ([`crate::ProcessingModel::with_light`]) the radiometric conversion
//! takes the lamp's power and colour from the light calibration instead of the simulator's
//! model: `W_c`, the camera-RGB signal rate of a white Lambertian reflector lit along its
//! normal from the nominal lamp distance, becomes `nominal_irradiance = W_g` and
//! `white_balance_c = W_g / W_c`.
//!
//! Drift: in every frame the holder plate's white area around the sample (between the markers,
//! outside the sample square; `btfrig_imaging::light::plate_patch_points`) is measured with the
//! pose the frame is rectified with. Its expected signal is `W_c * plate_c * g(p)` (the plate's
//! albedo relative to the white tile, `plate_c`, from the calibration), so the ratio
//!
//! ```text
//! lamp_factor_c = mean_p[ rate_c(p) / (vignetting * g(p)) ] / (W_c * plate_c)
//! ```
//!
//! is the lamp's output relative to the calibration, per channel (so a colour drift is caught
//! too). The texture is divided by it (through the white balance: camera RGB, before the colour
//! matrix).

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use btfrig_imaging::light::{lambertian_signal, plate_patch_points, rate_radiometry, LightError, PatchOptions};
use btfrig_imaging::{Radiometry, RgbSource};
use nalgebra::Point2;

/// What the light calibration says about one light.
#[derive(Debug, Clone, PartialEq)]
pub struct LampReference {
    /// Light id ("lamp" for the gonioreflectometer's lamp; an LED index for a dome).
    pub light: String,
    /// `W_c`: camera-RGB signal rate of a white Lambertian reflector lit along its normal from
    /// the nominal lamp distance, e-/s per photosite at gain 1.
    pub white_rate: [f64; 3],
    /// The holder plate's albedo relative to the white reference, per camera channel.
    pub plate_albedo: [f64; 3],
}

/// How the pipeline uses the light calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct LightCorrection {
    /// The calibration of the light every frame is lit by.
    pub reference: LampReference,
    /// Measure the lamp factor on the plate in every frame and divide the texture by it.
    pub correct_drift: bool,
    /// The plate points measured.
    pub patch: PatchOptions,
    /// A run whose lamp factor leaves `1 ± warn_drift` (any channel) gets a warning.
    pub warn_drift: f64,
}

impl LightCorrection {
    /// Calibrated power and colour, drift corrected, default patch, warning beyond 2 %.
    pub fn new(reference: LampReference) -> Self {
        LightCorrection { reference, correct_drift: true, patch: PatchOptions::default(), warn_drift: 0.02 }
    }

    /// Checks the reference: every figure finite and > 0.
    pub fn validate(&self) -> Result<(), LightError> {
        let r = &self.reference;
        const W: [&str; 3] = ["white_rate[0]", "white_rate[1]", "white_rate[2]"];
        const P: [&str; 3] = ["plate_albedo[0]", "plate_albedo[1]", "plate_albedo[2]"];
        for (names, vals) in [(W, r.white_rate), (P, r.plate_albedo)] {
            for (name, value) in names.into_iter().zip(vals) {
                if !(value.is_finite() && value > 0.0) {
                    return Err(LightError::Parameter { name, value, allowed: "finite and > 0" });
                }
            }
        }
        Ok(())
    }

    /// `radiometry` with the calibrated lamp power and colour, divided by `factor` per channel.
    pub fn apply(&self, radiometry: &Radiometry, factor: [f64; 3]) -> Radiometry {
        let w = self.reference.white_rate;
        Radiometry {
            nominal_irradiance: w[1],
            white_balance: std::array::from_fn(|c| w[1] / w[c] / factor[c]),
            ..*radiometry
        }
    }
}

/// The lamp's output in one frame relative to the light calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampFactor {
    /// Per camera channel.
    pub factor: [f64; 3],
    /// Standard error per channel (see `btfrig_imaging::light::WhiteSignal::sigma`).
    pub sigma: [f64; 3],
    /// Plate points used.
    pub points: usize,
}

/// Measures the lamp factor of one frame (demosaiced `image`, `pose` it is rectified with,
/// `radiometry` of the frame before any light calibration) on `points` of the plate.
pub fn measure_lamp_factor<I: RgbSource + ?Sized>(
    light: &LightCorrection,
    image: &I,
    camera: &CameraModel,
    pose: &ScenePose,
    lamp_distance_m: f64,
    radiometry: &Radiometry,
    points: &[Point2<f64>],
) -> Result<LampFactor, LightError> {
    let s = lambertian_signal(image, camera, pose, lamp_distance_m, &rate_radiometry(radiometry), points)?;
    let r = &light.reference;
    let expected: [f64; 3] = std::array::from_fn(|c| r.white_rate[c] * r.plate_albedo[c]);
    Ok(LampFactor {
        factor: std::array::from_fn(|c| s.mean[c] / expected[c]),
        sigma: std::array::from_fn(|c| s.sigma[c] / expected[c]),
        points: s.points,
    })
}

/// The plate points of `plate` per `light.patch`.
pub fn patch_points(light: &LightCorrection, plate: &PlateConfig) -> Vec<Point2<f64>> {
    plate_patch_points(plate, &light.patch)
}

/// One committed step's lamp figures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampStep {
    /// The capture.
    pub step: btfrig_store::StepId,
    /// Its lamp factor (`None`: not measured).
    pub factor: Option<LampFactor>,
    /// Its brightness error against the truth at the nominal lamp (`None`: no truth).
    pub brightness_err: Option<f64>,
}

/// Lamp factors and texture brightness over a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LampTotals {
    /// Every committed step with a factor or a brightness figure, in commit order.
    pub steps: Vec<LampStep>,
    /// Frames with a measured lamp factor.
    pub frames: u64,
    /// Smallest factor of any channel of any frame.
    pub factor_min: f64,
    /// Largest factor of any channel of any frame.
    pub factor_max: f64,
    /// Largest standard error of a factor.
    pub sigma_max: f64,
    /// Frames compared with the truth at the NOMINAL lamp (brightness figures below).
    pub compared: u64,
    /// Smallest `sum(texture) / sum(truth at the nominal lamp) - 1` of a frame.
    pub brightness_err_min: f64,
    /// Largest of the same.
    pub brightness_err_max: f64,
}

impl LampTotals {
    /// Adds one step's figures.
    pub fn add(&mut self, step: btfrig_store::StepId, factor: Option<LampFactor>, brightness_err: Option<f64>) {
        if let Some(f) = &factor {
            self.add_factor(f);
        }
        if let Some(e) = brightness_err {
            self.add_brightness(e);
        }
        if factor.is_some() || brightness_err.is_some() {
            self.steps.push(LampStep { step, factor, brightness_err });
        }
    }

    /// Adds one frame's factor.
    pub fn add_factor(&mut self, f: &LampFactor) {
        let (lo, hi) = f.factor.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        let s = f.sigma.iter().copied().fold(0.0, f64::max);
        if self.frames == 0 {
            (self.factor_min, self.factor_max, self.sigma_max) = (lo, hi, s);
        } else {
            self.factor_min = self.factor_min.min(lo);
            self.factor_max = self.factor_max.max(hi);
            self.sigma_max = self.sigma_max.max(s);
        }
        self.frames += 1;
    }

    /// Adds one frame's brightness error against the truth at the nominal lamp.
    pub fn add_brightness(&mut self, err: f64) {
        if !err.is_finite() {
            return;
        }
        if self.compared == 0 {
            (self.brightness_err_min, self.brightness_err_max) = (err, err);
        } else {
            self.brightness_err_min = self.brightness_err_min.min(err);
            self.brightness_err_max = self.brightness_err_max.max(err);
        }
        self.compared += 1;
    }

    /// Largest `|brightness error|`, `None` without compared frames.
    pub fn brightness_err_abs_max(&self) -> Option<f64> {
        (self.compared > 0).then(|| self.brightness_err_min.abs().max(self.brightness_err_max.abs()))
    }

    /// `(min, max)` lamp factor, `None` without measured frames.
    pub fn factor_range(&self) -> Option<(f64, f64)> {
        (self.frames > 0).then_some((self.factor_min, self.factor_max))
    }

    /// A warning when the factor left `1 ± threshold`.
    pub fn warning(&self, threshold: f64) -> Option<String> {
        let (lo, hi) = self.factor_range()?;
        ((1.0 - lo).max(hi - 1.0) > threshold).then(|| {
            format!(
                "lamp output drifted: lamp factor {lo:.4}..{hi:.4} over {} frames (threshold ±{threshold}); \
                 textures corrected by it",
                self.frames
            )
        })
    }
}

/// `sum(texture) / sum(truth) - 1` over texels and channels (`NaN` for a black truth).
pub fn brightness_error(tex: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
    let s = |v: &[[f32; 3]]| v.iter().flatten().map(|&x| f64::from(x)).sum::<f64>();
    let t = s(truth);
    if t > 0.0 {
        s(tex) / t - 1.0
    } else {
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn apply_divides_camera_rgb_by_the_factor() {
        let l = LightCorrection::new(LampReference {
            light: "lamp".into(),
            white_rate: [800.0, 1000.0, 600.0],
            plate_albedo: [0.8; 3],
        });
        let base = Radiometry {
            dn_range: 1.0,
            exposure_s: 1.0,
            dn_per_electron: 1.0,
            dark_e_per_s: 0.0,
            nominal_irradiance: 1.0,
            white_balance: [1.0; 3],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        // A white reflector under a lamp at 95 % (red 90 %): the factor takes it back to 1.
        let f = [0.90, 0.95, 0.95];
        let r = l.apply(&base, f);
        let white: [f32; 3] = std::array::from_fn(|c| (l.reference.white_rate[c] * f[c]) as f32);
        for v in r.convert(white, 1.0) {
            assert!((v - 1.0).abs() < 1e-6, "{v}");
        }
        let bad = LightCorrection {
            reference: LampReference { white_rate: [1.0, f64::NAN, 1.0], ..l.reference.clone() },
            ..l
        };
        assert!(matches!(bad.validate(), Err(LightError::Parameter { name: "white_rate[1]", .. })));
    }

    #[test]
    fn totals_track_range_and_warn() {
        let mut t = LampTotals::default();
        assert_eq!(t.factor_range(), None);
        t.add_factor(&LampFactor { factor: [0.99, 1.0, 1.01], sigma: [1e-3; 3], points: 100 });
        t.add_factor(&LampFactor { factor: [0.95, 0.96, 0.97], sigma: [2e-3; 3], points: 100 });
        assert_eq!(t.factor_range(), Some((0.95, 1.01)));
        assert_eq!(t.sigma_max, 2e-3);
        assert!(t.warning(0.02).is_some() && t.warning(0.1).is_none());
        t.add_brightness(-0.01);
        t.add_brightness(0.003);
        assert_eq!(t.brightness_err_abs_max(), Some(0.01));
    }
}
