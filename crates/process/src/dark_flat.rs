//! Dark and flat-field correction in the pipeline (measured in `btfrig_calibrate::dark_flat`,
//! numerics in [`btfrig_imaging::dark_flat`]; procedure and figures in `docs/dark-flat.md`).
//!
//! With a calibration ([`crate::ProcessingModel::with_dark_flat`]), every photosite is corrected
//! BEFORE demosaicing: `value = (DN - dark_dn(x, y, t, g)) / flat(x, y)`, hot photosites
//! replaced by their same-colour neighbours, then normalised like
//! `btfrig_imaging::demosaic::demosaic_bilinear` (divided by `white - black`). The radiometric
//! conversion then subtracts no dark current and divides by no lens vignetting: the flat
//! holds vignetting x PRNU, the dark model bias, column offsets and per-photosite dark current.
//!
//! The canonical linear intermediate for the HDR merge is [`photosite_rates`]
//! (`(DN - dark_dn) · e_per_dn / g / t / flat`, e-/s per photosite).

use btfrig_core::frame::RawFrame;
use btfrig_imaging::dark_flat::DarkFlatError;
pub use btfrig_imaging::dark_flat::{photosite_rates, DarkFlat, DarkModel, FlatField};
use btfrig_imaging::demosaic::{demosaic_bilinear_values, CameraRgbImage};

/// The frame corrected with `cal` and demosaiced, normalised so that `white - black` DN
/// above dark is 1 (what the radiometric conversion expects of the plain demosaic).
pub fn demosaic_corrected(frame: &RawFrame, cal: &DarkFlat) -> Result<CameraRgbImage, DarkFlatError> {
    let v = corrected_values(frame, cal)?;
    Ok(demosaic_bilinear_values(frame.width, frame.height, frame.meta.bayer, &v))
}

/// The photosites of [`demosaic_corrected`] before the demosaic: corrected with `cal`,
/// normalised so that `white - black` DN above dark is 1 (for a
/// [`btfrig_imaging::Mosaic::of_values`]).
pub fn corrected_values(frame: &RawFrame, cal: &DarkFlat) -> Result<Vec<f32>, DarkFlatError> {
    let range = (f32::from(frame.meta.white_level) - f32::from(frame.meta.black_level)).max(1.0);
    let mut v = cal.corrected_dn(frame)?;
    v.iter_mut().for_each(|x| *x /= range);
    Ok(v)
}

/// A vignetting map that is 1 wherever `vignetting` is positive (texels that project into the
/// image) and 0 elsewhere: the flat already divided the lens's vignetting out.
pub fn unit_vignetting(vignetting: Vec<f32>) -> Vec<f32> {
    vignetting.into_iter().map(|v| if v > 0.0 { 1.0 } else { 0.0 }).collect()
}
