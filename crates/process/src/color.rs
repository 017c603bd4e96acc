//! Colour correction of textures with a measured colour calibration (`docs/color.md`).
//!
//! Without one, [`crate::Processor::radiometry`] gives white-balanced camera RGB (the model's
//! notes say so). With one ([`crate::ProcessingModel::with_color`]), the radiometry uses the calibration's white
//! balance and no matrix, and the calibrated model maps the resulting camera RGB radiance
//! factor to linear sRGB radiance factor, texel by texel.

use btfrig_color::{ColorModel, ModelKind};

/// A colour correction: white balance, then a fitted model.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorCorrection {
    /// Where it came from (file name), for reports.
    pub name: String,
    /// Per-channel multipliers applied to camera RGB before the model.
    pub white_balance: [f64; 3],
    /// Camera RGB radiance factor (white-balanced) to linear sRGB radiance factor.
    pub model: ColorModel,
}

impl ColorCorrection {
    /// White balance only (an identity model): the uncorrected camera colours, for
    /// comparisons.
    pub fn white_balance_only(white_balance: [f64; 3]) -> ColorCorrection {
        let identity = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        ColorCorrection {
            name: "white balance only".into(),
            white_balance,
            model: ColorModel::from_coefficients(ModelKind::Linear, identity).expect("3 terms"),
        }
    }

    /// Applies the model to texels in place (texels outside the image are 0 and stay 0:
    /// every model term vanishes at 0).
    pub fn apply(&self, texels: &mut [[f32; 3]]) {
        self.model.apply_f32(texels);
    }
}
