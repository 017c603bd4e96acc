//! A flat-field source: a uniform-radiance field (a diffuser or integrating-sphere port filling
//! the lens's field of view) imaged through the TRUE lens onto the sensor.
//!
//! The photosite rate is `rate_c(x, y) = level_c · vignetting(x, y)`: a uniform radiance has
//! no geometry left, so what reaches the photosites differs only by the lens's relative
//! illumination; the sensor then adds PRNU, dark signal and noise. This is what a master flat
//! measures (`btfrig_calibrate::dark_flat`), and what the pipeline divides by in place of the
//! lens model's vignetting.

use rayon::prelude::*;

use crate::radiance::RadianceImage;
use crate::renderer::PixelRays;

/// The signal rate (e-/s per photosite, camera RGB) of a uniform-radiance field whose on-axis
/// rate is `level` (per channel), seen through `rays` (its vignetting at every pixel centre).
pub fn flat_field_radiance(rays: &impl PixelRays, level: [f64; 3]) -> RadianceImage {
    let (w, h) = (rays.width(), rays.height());
    let mut data = vec![[0.0f32; 3]; w * h];
    data.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        for (x, p) in row.iter_mut().enumerate() {
            let v = rays.vignetting(x as f64, y as f64);
            *p = level.map(|l| (l * v) as f32);
        }
    });
    RadianceImage { width: w, height: h, data }
}

/// The on-axis level (e-/s per photosite per channel) of a white diffuser lit by the lamp,
/// scaled so its brightest channel fills `fraction` of the full scale `full_scale_e` in
/// `exposure_s`: `camera_white` is the camera's response to the lamp's white
/// ([`crate::colour::ColourSystem::camera_white`]).
pub fn white_flat_level(camera_white: [f64; 3], fraction: f64, full_scale_e: f64, exposure_s: f64) -> [f64; 3] {
    let max = camera_white.iter().copied().fold(0.0f64, f64::max).max(1e-12);
    camera_white.map(|c| fraction * full_scale_e / exposure_s * c / max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::renderer::Pinhole;
    use crate::rig_scene::CachedCamera;
    use btfrig_core::camera::{CameraModel, Vignetting};
    use nalgebra::Point2;

    #[test]
    fn flat_field_follows_the_lens_vignetting_and_the_white_level() {
        let mut model = CameraModel::pinhole(64, 48, 40.0).unwrap();
        model.vignetting = Vignetting { cos4: true, poly: [-0.2, 0.0, 0.0] };
        let cam = CachedCamera::new(model.clone());
        let img = flat_field_radiance(&cam, [100.0, 200.0, 50.0]);
        for (x, y) in [(0, 0), (32, 24), (63, 47), (10, 40)] {
            let v = model.vignetting(Point2::new(x as f64, y as f64));
            let p = img.at(x, y);
            assert!((f64::from(p[1]) - 200.0 * v).abs() < 1e-3 && (f64::from(p[2]) - 50.0 * v).abs() < 1e-3);
        }
        assert!(img.at(0, 0)[1] < 0.8 * img.at(32, 24)[1], "corners darker");
        // A pinhole without vignetting gives a uniform field.
        let flat =
            flat_field_radiance(&Pinhole { width: 8, height: 8, fx: 10.0, fy: 10.0, cx: 3.5, cy: 3.5 }, [5.0; 3]);
        assert!(flat.data.iter().all(|p| *p == [5.0; 3]));
        let l = white_flat_level([0.5, 1.0, 0.8], 0.5, 40000.0, 0.1);
        assert_eq!(l, [100000.0, 200000.0, 160000.0]);
    }
}
