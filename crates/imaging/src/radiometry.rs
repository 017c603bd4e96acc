//! Radiometric conversion of a rectified texture to the ground truth's units: the radiance
//! factor in linear sRGB (D65), where a white Lambertian reflector lit along its normal from
//! the nominal lamp distance is `(1, 1, 1)`.
//!
//! Per texel and channel `c` (all parameters explicit, see [`Radiometry`]):
//!
//! ```text
//! rate_c   = (value_c * dn_range / (exposure_s * dn_per_electron)) - dark_e_per_s     [e-/s]
//! camera_c = rate_c / (vignetting * nominal_irradiance)        (white reflector -> camera white)
//! output   = matrix * (white_balance ⊙ camera)                  (white reflector -> (1, 1, 1))
//! ```

use btfrig_core::camera::CameraModel;
use btfrig_core::pose::ScenePose;
use nalgebra::Point3;
use rayon::prelude::*;

use crate::rectify::{check_geometry, sample_to_camera, RectifyError, Region, Texture};

/// The parameters of the conversion from demosaiced image values to radiance factor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Radiometry {
    /// DN above black per unit of image value: `white_level - black_level` for an image
    /// normalised like `btfrig_imaging::demosaic::demosaic_bilinear`, 1 for raw DN above black.
    pub dn_range: f64,
    /// Exposure time of the frame, seconds.
    pub exposure_s: f64,
    /// Conversion gain at the frame's analogue gain, DN per electron.
    pub dn_per_electron: f64,
    /// Dark current, electrons per second per photosite (subtracted; 0 if the dark level was
    /// already removed).
    pub dark_e_per_s: f64,
    /// Camera-RGB rate (green channel, e-/s per photosite) of a white Lambertian reflector
    /// facing the lamp at the nominal sample centre and distance, on the optical axis.
    pub nominal_irradiance: f64,
    /// Per-channel multipliers that make a white reflector `(1, 1, 1)` in camera RGB.
    pub white_balance: [f64; 3],
    /// Camera RGB (white-balanced) to linear sRGB.
    pub matrix: [[f64; 3]; 3],
}

impl Radiometry {
    fn validate(&self) -> Result<(), RectifyError> {
        let positive = [
            ("dn_range", self.dn_range),
            ("exposure_s", self.exposure_s),
            ("dn_per_electron", self.dn_per_electron),
            ("nominal_irradiance", self.nominal_irradiance),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(RectifyError::Radiometry { name, value, allowed: "finite and > 0" });
            }
        }
        if !(self.dark_e_per_s.is_finite() && self.dark_e_per_s >= 0.0) {
            return Err(RectifyError::Radiometry {
                name: "dark_e_per_s",
                value: self.dark_e_per_s,
                allowed: "finite and >= 0",
            });
        }
        for (i, v) in self.white_balance.iter().enumerate() {
            if !(v.is_finite() && *v > 0.0) {
                const NAMES: [&str; 3] = ["white_balance[0]", "white_balance[1]", "white_balance[2]"];
                return Err(RectifyError::Radiometry { name: NAMES[i], value: *v, allowed: "finite and > 0" });
            }
        }
        if let Some(v) = self.matrix.iter().flatten().find(|v| !v.is_finite()) {
            return Err(RectifyError::Radiometry { name: "matrix", value: *v, allowed: "finite entries" });
        }
        Ok(())
    }

    /// The radiance factor of one texel value seen with relative illumination `vignetting`.
    pub fn convert(&self, value: [f32; 3], vignetting: f64) -> [f32; 3] {
        let to_rate = self.dn_range / (self.exposure_s * self.dn_per_electron);
        let denom = vignetting * self.nominal_irradiance;
        let cam: [f64; 3] = std::array::from_fn(|c| {
            (f64::from(value[c]) * to_rate - self.dark_e_per_s) / denom * self.white_balance[c]
        });
        std::array::from_fn(|r| {
            (self.matrix[r][0] * cam[0] + self.matrix[r][1] * cam[1] + self.matrix[r][2] * cam[2]) as f32
        })
    }
}

/// The camera's relative illumination ([`CameraModel::vignetting`]) at the image position of
/// every texel centre of a `size x size` grid over `region`, row-major like a texture; 0 for
/// centres that do not project (those texels are 0 in the texture anyway).
pub fn vignetting_map(
    camera: &CameraModel,
    pose: &ScenePose,
    region: Region,
    size: usize,
) -> Result<Vec<f32>, RectifyError> {
    check_geometry(&region, size)?;
    let to_cam = sample_to_camera(pose);
    let mut out = vec![0.0f32; size * size];
    out.par_chunks_mut(size).enumerate().for_each(|(row, o)| {
        for (col, v) in o.iter_mut().enumerate() {
            let (x, y) = region.point(size, size, col as f64 + 0.5, row as f64 + 0.5);
            let p = to_cam.transform_point(&Point3::new(x, y, 0.0));
            if let Some(q) = camera.project(&p).filter(|q| camera.in_image(*q)) {
                *v = camera.vignetting_of_point(&p, q) as f32;
            }
        }
    });
    Ok(out)
}

/// Converts a rectified texture to the radiance factor (see the module documentation),
/// dividing each texel by `vignetting[texel]` (from [`vignetting_map`]). Texels with
/// vignetting 0 (outside the image) stay 0.
pub fn to_radiance_factor(tex: &Texture, vignetting: &[f32], r: &Radiometry) -> Result<Texture, RectifyError> {
    r.validate()?;
    if vignetting.len() != tex.data.len() {
        return Err(RectifyError::Mismatch { what: "vignetting map", got: vignetting.len(), expected: tex.data.len() });
    }
    let data = tex
        .data
        .par_iter()
        .zip(vignetting)
        .map(|(v, &vig)| if vig > 0.0 { r.convert(*v, f64::from(vig)) } else { [0.0; 3] })
        .collect();
    Ok(Texture { data, ..tex.clone() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_reflector_on_axis_is_one() {
        // A white reflector gives nominal_irradiance * camera_white e-/s; camera_white = 1/wb.
        let wb = [1.0 / 0.6, 1.0, 1.0 / 0.8];
        let r = Radiometry {
            dn_range: 4000.0,
            exposure_s: 0.2,
            dn_per_electron: 0.5,
            dark_e_per_s: 3.0,
            nominal_irradiance: 1e4,
            white_balance: wb,
            matrix: [[1.2, -0.1, -0.1], [-0.2, 1.3, -0.1], [0.0, -0.3, 1.3]],
        };
        let vig = 0.7;
        let value: [f32; 3] = std::array::from_fn(|c| {
            let e = (1e4 / wb[c] * vig + 3.0) * 0.2; // electrons
            (e * 0.5 / 4000.0) as f32
        });
        let out = r.convert(value, vig);
        for c in out {
            assert!((c - 1.0).abs() < 1e-5, "{out:?}");
        }
        let bad = Radiometry { exposure_s: 0.0, ..r };
        assert_eq!(
            bad.validate(),
            Err(RectifyError::Radiometry { name: "exposure_s", value: 0.0, allowed: "finite and > 0" })
        );
    }
}
